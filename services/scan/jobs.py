"""Job handler ``scan.inspect``: one JSON report and one preview PLY per input cloud."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path

from contract.context import JobContext, inputs_of_kind
from contract.errors import JobInputError
from services.lib.pointcloud.ply import PLY_MEDIA_TYPE, PlyError, write_ply
from services.scan.inspect import inspect_scan_file
from services.scan.kinds import PREVIEW, REPORT


def inspect_scan(ctx: JobContext) -> dict:
    clouds = inputs_of_kind(ctx, "scan", "cloud")
    if not clouds:
        raise JobInputError("scan.inspect needs at least one PLY artifact as input")
    params = ctx.params
    reports = {}
    share = 1.0 / len(clouds)
    for number, artifact in enumerate(clouds):
        base = number * share
        ctx.progress(base, f"inspecting {artifact.name}")
        try:
            inspected = inspect_scan_file(artifact.path, params)
        except (PlyError, ValueError) as exc:
            raise JobInputError(f"{artifact.name}: {exc}") from exc
        report, preview = inspected.report, inspected.preview
        stem = Path(artifact.name).stem
        preview_path = ctx.workdir / PREVIEW.file_name(stem)
        write_ply(preview_path, preview, comments=(f"preview of artifact {artifact.id}",))
        ctx.add_artifact_file(
            preview_path,
            kind=PREVIEW.kind,
            name=preview_path.name,
            media_type=PLY_MEDIA_TYPE,
            meta={"source_artifact_id": artifact.id, "point_count": len(preview.points)},
        )
        body = {"source_artifact_id": artifact.id, **asdict(report)}
        ctx.add_artifact_json(body, kind=REPORT.kind, name=REPORT.file_name(stem))
        reports[str(artifact.id)] = body
    ctx.progress(1.0, "done")
    return {"reports": reports}
