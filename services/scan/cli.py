"""``vista scan inspect``: what is in a PLY scan, as the ``scan.inspect`` job reports it."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import typer

from contract.cli import fail, params_options
from services.scan.kinds import ScanInspectParams

# numpy and scipy are imported inside the command: every `vista` invocation imports this.

scan_app = typer.Typer(
    help="What is in a scan: point count, bounds, spacing, density; a decimated preview.",
    no_args_is_help=True,
)


@scan_app.command("inspect")
@params_options(ScanInspectParams)
def inspect(
    cloud: Path = typer.Argument(..., exists=True, dir_okay=False, help="A PLY point cloud."),
    out: Path = typer.Option(None, "-o", "--out", help="Write the report as JSON here."),
    preview: Path = typer.Option(None, help="Write the decimated preview PLY here."),
    *,
    params: ScanInspectParams,
) -> None:
    """Check a PLY point cloud: point count (and how many measured), bounds, size, spacing
    (median nearest-neighbour distance), density and surface area; optionally a preview of
    at most --preview-points points, one per voxel."""
    from services.lib.pointcloud.ply import PlyError, write_ply
    from services.scan.inspect import inspect_scan_file

    try:
        inspected = inspect_scan_file(cloud, params)
    except (PlyError, ValueError) as exc:
        fail(f"{cloud}: {exc}")
    report = asdict(inspected.report)
    if out is not None:
        out.write_text(json.dumps(report, indent=2) + "\n")
    if preview is not None:
        write_ply(preview, inspected.preview, comments=(f"preview of {cloud.name}",))
    r = inspected.report
    grid = f"organized {r.grid_width} × {r.grid_height}" if r.organized else "unorganized"
    typer.echo(
        f"{cloud.name}: {r.point_count} points ({r.valid_point_count} measured, {grid}), "
        f"{r.size_mm[0]:.1f} × {r.size_mm[1]:.1f} × {r.size_mm[2]:.1f} mm, spacing "
        f"{r.mean_spacing_mm:.3f} mm, {r.density_per_mm2:.1f} points/mm²"
    )


def register(app: typer.Typer, simulate_app: typer.Typer, bench_app: typer.Typer) -> None:
    app.add_typer(scan_app, name="scan")
