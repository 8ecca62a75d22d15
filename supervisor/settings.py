"""vista settings: one class, read from ``VISTA_*`` environment variables.

The defaults give the embedded mode: a SQLite file and an artifact folder under
``VISTA_DATA_DIR`` and jobs run by a local pool of worker processes. Setting
``VISTA_DATABASE_URL`` (PostgreSQL) and ``VISTA_BROKER_URL`` (Redis or RabbitMQ) gives
the scale-out mode with ``vista worker`` processes on any number of machines, which must
then share ``VISTA_ARTIFACT_DIR`` (for example over NFS).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from services.lib.pointcloud.promises import ReaderLimits
from services.lib.process import available_cores, default_job_memory_mb

_READER = ReaderLimits()
"""The cloud readers' limits: read from the same variables by ``ReaderLimits.from_env``
where a reader runs; declared here so that a bad value stops the server at its start."""


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="VISTA_", extra="ignore")

    data_dir: Path = Field(
        Path("vista-data"), description="Folder for the SQLite file and artifacts."
    )
    database_url: str | None = Field(
        None, description="SQLAlchemy URL; unset = sqlite file `vista.db` in the data folder."
    )
    broker_url: str | None = Field(
        None, description="redis://… or amqp://…; unset = embedded job engine."
    )
    artifact_dir: Path | None = Field(
        None, description="Artifact storage folder; unset = `artifacts` in the data folder."
    )
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=1, le=65535)
    api_workers: int = Field(1, ge=1, description="API processes of `vista serve`.")
    access_log: bool = Field(False, description="Log every request (costs ~4 % under load).")
    max_upload_mb: int = Field(4096, ge=1, description="Largest artifact upload, MiB.")
    max_cloud_points: int = Field(
        _READER.max_points, ge=1, description="Most points a cloud upload's header may promise."
    )
    reader_memory_mb: int = Field(
        _READER.memory_mb,
        ge=256,
        description="Address space a cloud reader process may take beyond its loaded libraries, MiB.",
    )
    reader_cpu_s: int = Field(_READER.cpu_s, ge=1, description="CPU seconds of a cloud reader.")
    readers_at_once: int = Field(
        _READER.at_once, ge=1, description="Cloud readers at once on a host; beyond: 429."
    )
    embedded_workers: int = Field(2, ge=0, description="Worker processes of the embedded engine.")
    job_threads: int = Field(
        default_factory=available_cores,
        ge=1,
        le=256,
        description="Threads one job's algorithms run on (default: the cores available).",
    )
    job_memory_mb: int = Field(
        default_factory=default_job_memory_mb,
        ge=1024,
        description="Address space of one job worker process, MiB (default: ¾ of the "
        "machine's memory, at least 8192): a job that needs more fails with a sentence, "
        "and is not retried.",
    )
    heartbeat_interval_s: float = Field(5.0, gt=0, description="How often a running job beats.")
    heartbeat_timeout_s: float = Field(
        60.0, gt=0, description="A running job silent this long is taken as lost."
    )
    job_max_attempts: int = Field(3, ge=1, description="Attempts before a job fails for good.")
    job_time_limit_s: int = Field(6 * 3600, ge=1, description="Hard limit on one job attempt.")
    retry_backoff_s: float = Field(5.0, ge=0, description="First retry delay; doubles each time.")
    token_ttl_hours: float = Field(12.0, gt=0, description="Lifetime of a sign-in token.")
    cli_token_ttl_days: float = Field(
        90.0, gt=0, description="Default lifetime of a token made by `vista user token`."
    )
    device_token_ttl_days: float = Field(
        30.0, gt=0, description="Default lifetime of a headset's (device) token."
    )
    sign_in_per_account_per_min: int = Field(
        10, ge=1, description="Failed sign-ins one account may take per minute before 429."
    )
    sign_in_per_address_per_min: int = Field(
        30, ge=1, description="Sign-ins one client address may try per minute before 429."
    )
    sign_in_concurrency: int = Field(
        1, ge=1, description="Password checks (argon2, 64 MiB each) run at once per process."
    )
    sqlite_synchronous: Literal["FULL", "NORMAL"] = Field(
        "FULL",
        description="SQLite durability: FULL loses no acknowledged commit on power loss; "
        "NORMAL is faster (see `vista api bench`) but may lose the last commits.",
    )
    scene_max_points: int = Field(
        500_000, ge=1000, le=20_000_000, description="Points of the stitched cloud in scene.glb."
    )
    web_dir: Path | None = Field(
        None, description="The dashboard's built files; unset = clients/web/dist of the source."
    )
    extra_job_kinds: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="Extra modules declaring job kinds in a KINDS tuple (comma separated).",
    )

    @field_validator("extra_job_kinds", mode="before")
    @classmethod
    def _split_modules(cls, value: object) -> object:
        if isinstance(value, str):
            return [part.strip() for part in value.split(",") if part.strip()]
        return value

    @property
    def resolved_database_url(self) -> str:
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'vista.db').resolve()}"

    @property
    def resolved_artifact_dir(self) -> Path:
        return (self.artifact_dir or self.data_dir / "artifacts").resolve()

    @property
    def max_upload_bytes(self) -> int:
        return self.max_upload_mb * 1024 * 1024


def secure_data_dir(settings: Settings) -> None:
    """The data folder only its owner can enter (700) and the SQLite files only its owner
    can read (600): the database holds password hashes and the inspection record."""
    folder = settings.data_dir
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    folder.chmod(0o700)
    private = [folder / "engine.lock"]
    url = settings.resolved_database_url
    if url.startswith("sqlite:///"):
        database = Path(url.removeprefix("sqlite:///"))
        private += [database, Path(f"{database}-wal"), Path(f"{database}-shm")]
    for path in private:
        if path.exists():
            path.chmod(0o600)


@lru_cache
def get_settings() -> Settings:
    return Settings()
