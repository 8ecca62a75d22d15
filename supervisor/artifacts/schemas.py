from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field

ARTIFACT_KIND_PATTERN = r"^[a-z][a-z0-9_.-]{0,31}$"
MEDIA_TYPES = {
    "application/x-ply": ".ply",
    "application/json": ".json",
    "application/octet-stream": "",
    "image/png": ".png",
    "image/jpeg": ".jpg",
    "text/plain": ".txt",
    "text/csv": ".csv",
    "model/gltf-binary": ".glb",
    "model/stl": ".stl",
    "model/obj": ".obj",
    "model/gltf+json": ".gltf",
    "model/step": ".step",
    "application/zip": ".zip",
    "application/gzip": ".tar.gz",
    "application/x-bzip2": ".tar.bz2",
    "application/x-xz": ".tar.xz",
    "application/x-tar": ".tar",
}


class ArtifactKindOut(BaseModel):
    name: str
    description: str = Field(description="What a file of this kind is: units and frames.")


class ArtifactOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    inspection_id: int
    kind: str
    name: str
    media_type: str
    size_bytes: int
    sha256: str
    meta: dict
    job_id: int | None
    run_id: int | None = Field(
        None, description="The run of the job that made it (null: uploaded)."
    )
    step: str | None = Field(None, description="That job's step in its run.")
    created_by: int | None
    created_by_name: str | None = Field(None, description="Who uploaded it.")
    created_at: datetime
