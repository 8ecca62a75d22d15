"""The inspection's 3D scene as binary glTF, with ETags."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.concurrency import run_in_threadpool

from supervisor.deps import READ_ROLES, CurrentUser, get_runtime, require
from supervisor.engine.runtime import Runtime
from supervisor.exports.cache import OpenFileResponse
from supervisor.exports.job_scene import job_scene_file
from supervisor.exports.scene import SceneRun, scene_runs
from supervisor.exports.service import scene_file
from supervisor.ids import IdPath
from supervisor.inspections.service import get as get_inspection
from supervisor.requests import JsonGuardRoute

router = APIRouter(route_class=JsonGuardRoute, tags=["exports"])
readers = require(*READ_ROLES, action="read scenes")
GLB_MEDIA_TYPE = "model/gltf-binary"


@router.get(
    "/inspections/{inspection_id}/scene.glb",
    response_class=Response,
    responses={
        200: {"content": {GLB_MEDIA_TYPE: {}}, "description": "The scene (binary glTF 2.0)."},
        304: {"description": "Not modified since the ETag in If-None-Match."},
    },
)
async def scene_glb(
    inspection_id: IdPath,
    request: Request,
    points: int | None = Query(
        None, ge=1000, le=20_000_000, description="Point budget (default: the server's)."
    ),
    run: int | None = Query(
        None,
        ge=1,
        le=2**63 - 1,
        description="The measured run to show (`GET …/scene-runs` lists them); default the newest.",
    ),
    runtime: Runtime = Depends(get_runtime),
    _: CurrentUser = Depends(readers),
) -> Response:
    """The scene of what is judged, as glTF 2.0 in metres, +Y up (converted from the base
    frame, mm, +Z up; `asset.extras.gltf_T_base` holds the conversion): the cloud one run
    measured as points with colours, what its measurement drew on it (panel outlines,
    seams), panel meshes, a node `defect-<id>` per defect that run found (and per defect
    added by hand) with its data in `extras`, and a node `marker-<name>` per image marker;
    `asset.extras.scene_run` names the run. Without `run`, the newest measured run's (before
    any measurement: the newest cloud). Send the ETag back in `If-None-Match` to get 304
    while nothing in the scene changed."""
    max_points = points or runtime.settings.scene_max_points
    etag, handle = await run_in_threadpool(
        scene_file, runtime, inspection_id, max_points, request.headers.get("if-none-match"), run
    )
    headers = {"ETag": etag, "Cache-Control": "private, no-cache"}
    if handle is None:
        return Response(status_code=304, headers=headers)
    return OpenFileResponse(handle, media_type=GLB_MEDIA_TYPE, headers=headers)


@router.get("/inspections/{inspection_id}/scene-runs", response_model=list[SceneRun])
def list_scene_runs(
    inspection_id: IdPath,
    runtime: Runtime = Depends(get_runtime),
    _: CurrentUser = Depends(readers),
) -> list[SceneRun]:
    """The inspection's measured runs, newest first — each a scene of its own (`scene.glb?run=`):
    the run, its measuring job, the cloud it read."""
    with runtime.db.read() as session:
        get_inspection(session, inspection_id=inspection_id)
        return scene_runs(session, inspection_id=inspection_id)


@router.get(
    "/jobs/{job_id}/scene.glb",
    response_class=Response,
    responses={
        200: {"content": {GLB_MEDIA_TYPE: {}}, "description": "The job's scene (binary glTF 2.0)."}
    },
)
async def job_scene_glb(
    job_id: IdPath,
    points: int | None = Query(
        None, ge=1000, le=20_000_000, description="Point budget (default: the server's)."
    ),
    runtime: Runtime = Depends(get_runtime),
    _: CurrentUser = Depends(readers),
) -> Response:
    """A job's results in 3D as glTF 2.0 (metres, +Y up), as its kind declares them: an
    odometry run's path with its σ, a depth prediction's clouds, a track's scans with the
    box moving one key a frame (the animation ``frames``; each scan shown for its frame)
    and the true box when the drive had labels. Node ``job-<id>``'s extras hold the run's
    figures."""
    handle = await run_in_threadpool(
        job_scene_file, runtime, job_id, points or runtime.settings.scene_max_points
    )
    return OpenFileResponse(handle, media_type=GLB_MEDIA_TYPE, headers={"Cache-Control": "private"})
