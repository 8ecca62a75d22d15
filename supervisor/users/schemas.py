from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from supervisor.models.users import Role
from supervisor.requests import RequestModel


class UserCreate(RequestModel):
    username: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.@-]+$")
    role: Role
    password: str | None = Field(
        None, min_length=8, max_length=1024, description="Omit for device accounts (tokens only)."
    )

    @model_validator(mode="after")
    def _people_sign_in(self) -> UserCreate:
        if self.role != "device" and self.password is None:
            raise ValueError(f"a {self.role} account needs a password (at least 8 characters)")
        return self


class UserOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    username: str
    role: Role
    active: bool
    created_at: datetime


class TokenCreate(RequestModel):
    name: str = Field(min_length=1, max_length=128, description="What the token is for.")
    kind: Literal["device", "cli"] = "device"
    ttl_hours: float | None = Field(
        None, gt=0, le=24 * 3650, description="Lifetime; omit for a token that does not expire."
    )


class TokenCreated(BaseModel):
    token: str = Field(description="Shown once; only its hash is stored.")
    name: str
    kind: str
    user_id: int
    expires_at: datetime | None
