"""Point clouds written by other programs' libraries (not vista's writer), one per format a
scanner or CloudCompare exports, with the truth to compare them with."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

HEIGHT, WIDTH = 12, 16
HOLES = (5, 37, 100)
"""Grid pixels the sensor did not measure."""
UTM_M = np.array([512_345.0, 5_401_234.0, 310.0])
"""Where a LAS survey sits (UTM, metres): too far for float32 millimetres as it is."""


@dataclass(frozen=True)
class Truth:
    points_m: np.ndarray
    """(H*W, 3) metres; the holes' rows NaN."""
    colors: np.ndarray
    """(H*W, 3) uint8."""
    intensity: np.ndarray
    """(H*W,) float32."""


def truth() -> Truth:
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH]
    points = np.stack([cols * 0.002, rows * 0.003, 0.5 + 0.001 * rows * cols], -1).reshape(-1, 3)
    points[list(HOLES)] = np.nan
    index = np.arange(HEIGHT * WIDTH)
    colors = np.stack([index % 256, (index * 7) % 256, (index * 13) % 256], -1).astype(np.uint8)
    return Truth(points, colors, (index % 97).astype(np.float32))


def measured(t: Truth) -> np.ndarray:
    return np.isfinite(t.points_m).all(axis=1)


def write_ply_ascii_open3d(path: Path, t: Truth) -> None:
    """CloudCompare-like ASCII PLY with colours (Open3D's writer), millimetres."""
    import open3d as o3d

    keep = measured(t)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(t.points_m[keep] * 1000.0))
    cloud.colors = o3d.utility.Vector3dVector(t.colors[keep] / 255.0)
    assert o3d.io.write_point_cloud(str(path), cloud, write_ascii=True)


def write_ply_big_endian(path: Path, t: Truth) -> None:
    """Big-endian PLY of an organised scan (plyfile's writer): vista's grid comments,
    intensity, NaN holes; millimetres in float64."""
    from plyfile import PlyData, PlyElement

    rows = np.empty(
        len(t.points_m), dtype=[("x", ">f8"), ("y", ">f8"), ("z", ">f8"), ("intensity", ">f4")]
    )
    rows["x"], rows["y"], rows["z"] = (t.points_m * 1000.0).T
    rows["intensity"] = t.intensity
    ply = PlyData(
        [PlyElement.describe(rows, "vertex")],
        byte_order=">",
        comments=[f"width {WIDTH}", f"height {HEIGHT}"],
    )
    ply.write(str(path))


def write_pcd(path: Path, t: Truth) -> None:
    """An organised PCD (pypcd4's writer), metres, packed rgb and intensity, binary."""
    from pypcd4 import PointCloud as Pcd

    rgb = Pcd.encode_rgb(t.colors)
    data = np.column_stack([t.points_m.astype(np.float32), t.intensity, rgb])
    pcd = Pcd.from_points(
        data,
        ("x", "y", "z", "intensity", "rgb"),
        (np.float32, np.float32, np.float32, np.float32, np.float32),
    )
    pcd.metadata.width, pcd.metadata.height = WIDTH, HEIGHT
    pcd.save(path)


def write_las(path: Path, t: Truth, *, compressed: bool) -> None:
    """A LAS 1.4 survey (laspy's writer; LAZ through lazrs) in UTM metres: 16-bit colour,
    intensity, 0.1 mm resolution."""
    import laspy

    keep = measured(t)
    points = t.points_m[keep] + UTM_M
    header = laspy.LasHeader(point_format=3, version="1.4")
    header.offsets = np.floor(points.min(axis=0))
    header.scales = np.array([0.0001, 0.0001, 0.0001])
    las = laspy.LasData(header)
    las.x, las.y, las.z = points.T
    las.intensity = t.intensity[keep].astype(np.uint16)
    colors16 = t.colors[keep].astype(np.uint16) * 257
    las.red, las.green, las.blue = colors16.T
    las.write(str(path), laz_backend=laspy.LazBackend.Lazrs if compressed else None)


def write_e57(path: Path, t: Truth) -> None:
    """One structured E57 scan (libE57Format through pye57): row and column indices,
    intensity, colour; the holes not written."""
    import pye57

    keep = measured(t)
    rows, cols = np.divmod(np.arange(HEIGHT * WIDTH), WIDTH)
    e57 = pye57.E57(str(path), mode="w")
    e57.write_scan_raw(
        {
            "cartesianX": t.points_m[keep, 0],
            "cartesianY": t.points_m[keep, 1],
            "cartesianZ": t.points_m[keep, 2],
            "intensity": t.intensity[keep] / 100.0,
            "colorRed": t.colors[keep, 0],
            "colorGreen": t.colors[keep, 1],
            "colorBlue": t.colors[keep, 2],
            "rowIndex": rows[keep].astype(np.int32),
            "columnIndex": cols[keep].astype(np.int32),
        }
    )
    e57.close()


def write_xyz(path: Path, t: Truth) -> None:
    """CloudCompare's ASCII export: a '//X Y Z R G B' line, then millimetres and colour."""
    keep = measured(t)
    rows = np.column_stack([t.points_m[keep] * 1000.0, t.colors[keep]])
    np.savetxt(path, rows, fmt=["%.6f"] * 3 + ["%d"] * 3, header="X Y Z R G B", comments="//")


def write_pts(path: Path, t: Truth) -> None:
    """Leica PTS: the point count, then x y z intensity r g b in metres."""
    keep = measured(t)
    rows = np.column_stack([t.points_m[keep], t.intensity[keep], t.colors[keep]])
    np.savetxt(path, rows, fmt=["%.6f"] * 4 + ["%d"] * 3, header=str(int(keep.sum())), comments="")
