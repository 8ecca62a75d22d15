"""Kinematic stitching (thesis 6.1.1): every scan into the base frame through
``base_T_scan_i = base_T_flange_i @ flange_T_sensor``, then clean and merge.

Per scan (on its grid when organized): normals, LoOP outlier probabilities, removal of
probable outliers. Then all scans in the base frame, closest vertices merged per voxel
(normals and intensity averaged), and voxels left isolated removed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from contract.vocabulary import Progress
from services.lib.pointcloud.grid import smooth_grid_normals, surrounded
from services.lib.pointcloud.ply import PointCloud
from services.lib.pointcloud.transforms import apply
from services.stitching.clean import isolated_points, loop_grid, loop_unorganized, voxel_merge
from services.stitching.icp import Alignment, IcpConfig, refine_poses
from services.stitching.kinds import NoiseModel, StitchParams

SETTINGS = StitchParams.model_fields
"""The stitch's settings a job or command sets: their defaults and ranges."""


@dataclass(frozen=True)
class StitchConfig:
    voxel_mm: float = SETTINGS["voxel_mm"].default
    """Edge of the voxels whose points are merged into one vertex."""
    loop_radius_px: int = 1
    """LoOP context: the measured neighbours in a (2r+1)² grid window."""
    normal_span_mm: float = 2.0
    """Normals of organized scans from central differences about this long."""
    loop_neighbours: int = 8
    """LoOP context of unorganized scans: k nearest neighbours."""
    loop_threshold: float = SETTINGS["loop_threshold"].default
    """Points with a higher outlier probability are removed."""
    filter_cell_mm: float = 2.0
    min_points: int = 10
    """Final filter: merged points whose 2 mm cell and its 26 neighbours hold fewer than
    this many points are removed (stray returns and spray)."""
    icp: IcpConfig | None = None
    """Move the cleaned scans by ICP before merging (None: kinematic poses only)."""

    def __post_init__(self) -> None:
        StitchParams(voxel_mm=self.voxel_mm, loop_threshold=self.loop_threshold)  # its ranges

    @classmethod
    def from_params(cls, params: StitchParams, calibration: dict) -> StitchConfig:
        """The stitch a job's or command's parameters ask for; a ``bounded`` ICP bounded by
        the robot noise the calibration was given and by its own uncertainty, as its
        HANDEYE.json ``calibration`` records them (the defaults where it does not)."""
        icp = None
        if params.icp != "none":
            noise = NoiseModel.model_validate(calibration.get("noise") or {})
            icp = IcpConfig(
                method=params.icp,
                start=params.icp_start,
                robot_sigma_mm=noise.robot_sigma_mm,
                robot_sigma_deg=noise.robot_sigma_deg,
                calibration_sigma_mm=float(calibration.get("sigma_translation_mm") or 0.0),
                calibration_sigma_deg=float(calibration.get("sigma_rotation_deg") or 0.0),
            )
        return cls(voxel_mm=params.voxel_mm, loop_threshold=params.loop_threshold, icp=icp)


@dataclass(frozen=True)
class CleanScan:
    """One scan after its own clean-up, in the base frame."""

    points: np.ndarray
    """(N, 3) float32, mm, base frame."""
    normals: np.ndarray | None
    intensity: np.ndarray | None
    colors: np.ndarray | None
    measured: int
    outliers: int
    surrounded: np.ndarray | None = None
    """(N,) bool: points with a full neighbourhood on their own surface, the ones ICP
    aligns (edges and borders are kept in the cloud but their one-sided normals are
    less sure); None: all."""


@dataclass(frozen=True)
class StitchResult:
    cloud: PointCloud
    scans: list[CleanScan]
    base_T_scan: np.ndarray
    isolated_removed: int
    seconds: dict[str, float] = field(default_factory=dict)
    alignments: list[Alignment] | None = None
    """Per scan, what ICP did (``config.icp`` only)."""


def clean_scan(cloud: PointCloud, base_T_scan: np.ndarray, config: StitchConfig) -> CleanScan:
    """Normals and LoOP on the scan's own grid (or k-NN), outliers out, into the base frame."""
    if cloud.grid_shape is not None:
        grid = cloud.points.reshape(*cloud.grid_shape, 3)
        probability = loop_grid(grid, radius_px=config.loop_radius_px).ravel()
        normals = smooth_grid_normals(grid, config.normal_span_mm).reshape(-1, 3)
        inner = surrounded(grid).ravel()
    else:
        finite = np.isfinite(cloud.points).all(axis=1)
        probability = np.full(len(cloud.points), np.nan)
        probability[finite] = loop_unorganized(
            cloud.points[finite], neighbours=config.loop_neighbours
        )
        normals = cloud.normals
        inner = None
    measured = np.isfinite(probability)
    keep = measured & (probability <= config.loop_threshold)
    if normals is not None:
        keep &= np.isfinite(normals).all(axis=1)
    rotated_normals = None
    if normals is not None:
        rotated_normals = normals[keep] @ base_T_scan[:3, :3].T.astype(np.float32)
    return CleanScan(
        points=apply(base_T_scan, cloud.points[keep]),
        normals=rotated_normals,
        intensity=None if cloud.intensity is None else cloud.intensity[keep],
        colors=None if cloud.colors is None else cloud.colors[keep],
        measured=int(measured.sum()),
        outliers=int((measured & (probability > config.loop_threshold)).sum()),
        surrounded=None if inner is None else inner[keep],
    )


def stitch(
    clouds: list[PointCloud],
    base_T_flange: np.ndarray,
    flange_T_sensor: np.ndarray,
    *,
    config: StitchConfig | None = None,
    progress: Progress | None = None,
) -> StitchResult:
    """Stitch scans taken at ``base_T_flange`` (n, 4, 4) with the calibrated mount."""
    config = config or StitchConfig()
    if len(clouds) != len(base_T_flange):
        raise ValueError(f"{len(clouds)} scans but {len(base_T_flange)} robot poses")
    if not clouds:
        raise ValueError("no scans to stitch")
    report = progress or (lambda fraction, message: None)
    seconds: dict[str, float] = {}
    started = time.perf_counter()
    base_T_scan = base_T_flange @ flange_T_sensor
    clean_share = 0.8 if config.icp is None else 0.6
    cleaned = []
    for i, cloud in enumerate(clouds):
        report(clean_share * i / len(clouds), f"cleaning scan {i + 1} of {len(clouds)}")
        cleaned.append(clean_scan(cloud, base_T_scan[i], config))
    seconds["clean_scans_s"] = time.perf_counter() - started

    alignments = None
    if config.icp is not None:
        started = time.perf_counter()
        inner = [slice(None) if s.surrounded is None else s.surrounded for s in cleaned]
        alignments = refine_poses(
            [s.points[i] for s, i in zip(cleaned, inner, strict=True)],
            [
                None if s.normals is None else s.normals[i]
                for s, i in zip(cleaned, inner, strict=True)
            ],
            base_T_scan,
            flange_T_sensor,
            config.icp,
            progress=lambda i: report(
                0.6 + 0.2 * i / len(clouds), f"ICP: aligning scan {i + 1} of {len(clouds)}"
            ),
        )
        cleaned = [_moved(s, a.correction) for s, a in zip(cleaned, alignments, strict=True)]
        base_T_scan = np.stack([a.correction for a in alignments]) @ base_T_scan
        seconds["icp_s"] = time.perf_counter() - started

    report(0.8, "merging closest vertices")
    started = time.perf_counter()
    has_normals = all(s.normals is not None for s in cleaned)
    has_intensity = all(s.intensity is not None for s in cleaned)
    has_colors = all(s.colors is not None for s in cleaned)
    merged = voxel_merge(
        np.concatenate([s.points for s in cleaned]),
        config.voxel_mm,
        normals=np.concatenate([s.normals for s in cleaned]) if has_normals else None,
        intensity=np.concatenate([s.intensity for s in cleaned]) if has_intensity else None,
        colors=np.concatenate([s.colors for s in cleaned]) if has_colors else None,
    )
    seconds["merge_s"] = time.perf_counter() - started

    report(0.9, "removing isolated vertices")
    started = time.perf_counter()
    keep = ~isolated_points(
        merged.points, cell_mm=config.filter_cell_mm, min_points=config.min_points
    )
    cloud = PointCloud(
        points=merged.points[keep],
        normals=None if merged.normals is None else merged.normals[keep],
        intensity=None if merged.intensity is None else merged.intensity[keep],
        colors=None if merged.colors is None else merged.colors[keep],
    )
    seconds["filter_s"] = time.perf_counter() - started
    report(1.0, f"stitched {len(clouds)} scans into {len(cloud.points)} points")
    return StitchResult(cloud, cleaned, base_T_scan, int((~keep).sum()), seconds, alignments)


def _moved(scan: CleanScan, correction: np.ndarray) -> CleanScan:
    rotation = correction[:3, :3].T.astype(np.float32)
    return replace(
        scan,
        points=apply(correction, scan.points),
        normals=None if scan.normals is None else scan.normals @ rotation,
    )
