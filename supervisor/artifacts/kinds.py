"""The kinds of artifact an inspection keeps, and the file format each must have."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Format = Literal[
    "ply",
    "ply-mesh",
    "json",
    "png",
    "glb",
    "archive",
    "onnx",
    "tum",
    "image",
    "depth-png",
    "drive",
    "lidar",
]


@dataclass(frozen=True)
class ArtifactKind:
    name: str
    format: Format | None
    """What the content must be, whatever media type was declared; ``None``: any file."""
    description: str


ARTIFACT_KINDS = {
    kind.name: kind
    for kind in (
        ArtifactKind("scan", "ply", "One scan as the sensor took it, sensor frame, mm."),
        ArtifactKind("cloud", "ply", "A stitched point cloud in the robot's base frame, mm."),
        ArtifactKind("preview", "ply", "A decimated copy of a cloud for viewers."),
        ArtifactKind("mesh", "ply-mesh", "Nominal panel surfaces as a PLY triangle mesh."),
        ArtifactKind("pairs", "json", "Robot–plate pose pairs for hand-eye calibration."),
        ArtifactKind("scans", "json", "The list of scans with each scan's robot pose."),
        ArtifactKind("handeye", "json", "A hand-eye calibration (flange_T_sensor)."),
        ArtifactKind("report", "json", "A job's or a tool's report."),
        ArtifactKind("plot", "png", "A figure."),
        ArtifactKind("scene", "glb", "A 3D scene for viewers (binary glTF)."),
        ArtifactKind(
            "frames",
            "archive",
            "A camera's frame sequence: a zip or tar of PNG frames in one folder with "
            "camera.json (size, fps, mm/px) and, when known, truth.tum.",
        ),
        ArtifactKind(
            "model", "onnx", "A learned model: ONNX with vista's metadata (its training command)."
        ),
        ArtifactKind(
            "trajectory", "tum", "A camera trajectory in the TUM format (t tx ty tz qx qy qz qw)."
        ),
        ArtifactKind("image", "image", "A camera image (PNG or JPEG)."),
        ArtifactKind(
            "depth",
            "depth-png",
            "A depth map in KITTI's convention: 16-bit grey PNG, metres × 256, 0 = none.",
        ),
        ArtifactKind(
            "drive",
            "drive",
            "A camera drive in KITTI's layout as a zip or tar: image_02/ and its calibration "
            "(calib.json or calib_cam_to_cam.txt), with image_03/, depth/, poses.txt as known.",
        ),
        ArtifactKind(
            "lidar",
            "lidar",
            "A LiDAR sequence in KITTI's formats as a zip or tar: velodyne/NNNNNN.bin and "
            "calib.txt, with label_02.txt and poses.txt as known.",
        ),
        ArtifactKind("other", None, "Any file kept with the inspection; no job reads it."),
    )
}
ArtifactKindName = Literal[tuple(ARTIFACT_KINDS)]  # the names above, for the API schema
