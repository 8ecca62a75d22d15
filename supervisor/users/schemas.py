from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from supervisor.models.users import Role
from supervisor.requests import RequestId, RequestModel


class UserCreate(RequestModel):
    """A person's account needs a password; a device's has none (it signs in with tokens)."""

    model_config = ConfigDict(
        json_schema_extra={
            "if": {"properties": {"role": {"const": "device"}}},
            "else": {"required": ["password"], "properties": {"password": {"type": "string"}}},
        }
    )

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
        None,
        gt=0,
        le=24 * 3650,
        description="Lifetime in hours; omit for the default of its kind (settings "
        "VISTA_DEVICE_TOKEN_TTL_DAYS, VISTA_CLI_TOKEN_TTL_DAYS). Every token expires.",
    )


class TokenCreated(BaseModel):
    token: str = Field(description="Shown once; only its hash is stored.")
    name: str
    kind: str
    user_id: int
    expires_at: datetime


class UserUpdate(RequestModel):
    active: bool | None = Field(
        None, description="false: deactivate (their tokens stop at once); true: reactivate."
    )
    role: Role | None = None
    password: str | None = Field(None, min_length=8, max_length=1024)


class TokenInfo(BaseModel):
    """A token as listed: never the token itself (only its hash is stored)."""

    id: int
    user_id: int
    username: str
    name: str
    kind: str
    created_at: datetime
    expires_at: datetime | None
    revoked: bool
    revoked_at: datetime | None
    current: bool = Field(False, description="The token this request was made with.")


class RevokeRequest(RequestModel):
    """Give exactly one of `user_id` and `device` (null counts as not given)."""

    model_config = ConfigDict(
        json_schema_extra={
            "oneOf": [
                {"required": ["user_id"], "properties": {"user_id": {"type": "integer"}}},
                {"required": ["device"], "properties": {"device": {"type": "string"}}},
            ]
        }
    )

    user_id: RequestId | None = Field(
        None, description="Revoke every token of this user (yours, unless admin)."
    )
    device: str | None = Field(
        None,
        min_length=1,
        max_length=128,
        description="Revoke every device token of this name (a lost headset; admins).",
    )
    reason: str = Field("", max_length=2000, description="Kept in the audit log.")

    @model_validator(mode="after")
    def _one_target(self) -> RevokeRequest:
        if (self.user_id is None) == (self.device is None):
            raise ValueError("give exactly one of user_id and device")
        return self


class RevokedOut(BaseModel):
    revoked: list[int] = Field(description="Ids of the tokens revoked now.")


class PasswordChange(RequestModel):
    current_password: str = Field(min_length=1, max_length=1024)
    new_password: str = Field(min_length=8, max_length=1024)
