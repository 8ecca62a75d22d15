from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, ConfigDict


class AuditEventOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    created_at: datetime
    user_id: int | None
    username: str
    action: str
    entity: str
    entity_id: int
    inspection_id: int | None
    before: dict | None
    after: dict | None
    reason: str
