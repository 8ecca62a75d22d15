from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field

from supervisor.requests import RequestModel


class TokenRequest(RequestModel):
    username: str = Field(min_length=1, max_length=64)
    password: str = Field(min_length=1, max_length=1024)


class TokenOut(BaseModel):
    access_token: str
    token_type: Literal["bearer"] = "bearer"
    expires_at: datetime | None


class MeOut(BaseModel):
    id: int
    username: str
    role: str
    token_kind: str
