"""What every training command and job takes, whichever network it trains: the passes, the
optimiser's step, the seed and the device. A service's training ``Params`` extends it (with
its own defaults where its network has them); its command's options come from there."""

from __future__ import annotations

from dataclasses import fields
from typing import TypeVar

from pydantic import BaseModel, ConfigDict, Field

from contract.vocabulary import DeviceChoice

Config = TypeVar("Config")


class TrainSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")

    epochs: int | None = Field(
        None, ge=1, le=10_000, description="Passes over the data (default the network's)."
    )
    learning_rate: float | None = Field(
        None, gt=0, le=10, description="The optimiser's step (default the network's)."
    )
    seed: int = Field(
        0, ge=0, le=2**31 - 1, description="Random seed: split, initial weights, shuffling."
    )
    device: DeviceChoice = Field(
        "auto", description="auto: CUDA where torch sees a GPU, else the CPU; or cpu, cuda."
    )


def config_from(config_type: type[Config], params: BaseModel, **more: object) -> Config:
    """An algorithm's config dataclass from a job's or command's ``params``: the fields both
    have (a setting left ``None``: the config's default) and ``more`` (threads …)."""
    names = {f.name for f in fields(config_type)}
    given = {k: v for k, v in params.model_dump().items() if k in names and v is not None}
    return config_type(**given, **more)
