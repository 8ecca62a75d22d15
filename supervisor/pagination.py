"""Cursor pagination over a monotonically increasing integer id."""

from __future__ import annotations

import base64
import binascii
from collections.abc import Callable, Sequence
from typing import Annotated, Generic, TypeVar

from fastapi import Query
from pydantic import BaseModel
from sqlalchemy import Select
from sqlalchemy.orm import Session

from supervisor.ids import MAX_ID
from supervisor.problems import Problem

T = TypeVar("T")
Item = TypeVar("Item", bound=BaseModel)
DEFAULT_LIMIT = 100
MAX_LIMIT = 500
Limit = Annotated[int, Query(ge=1, le=MAX_LIMIT, description="Items per page.")]


class Page(BaseModel, Generic[T]):
    items: list[T]
    next_cursor: str | None = None


def encode_cursor(last_id: int) -> str:
    return base64.urlsafe_b64encode(f"id:{last_id}".encode()).decode().rstrip("=")


def decode_cursor(cursor: str | None) -> int:
    """The id after which the next page starts (0 = from the start)."""
    if not cursor:
        return 0
    try:
        text = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)).decode()
        prefix, _, value = text.partition(":")
        if prefix != "id" or not value.isdigit() or int(value) > MAX_ID:
            raise ValueError(text)
        return int(value)
    except (ValueError, binascii.Error, UnicodeDecodeError) as exc:
        raise Problem(400, "The cursor is not one this server gave out; start without it.") from exc


def paginate(
    session: Session,
    query: Select,
    *,
    cursor: str | None,
    limit: int,
    item: type[Item],
    out: Callable[[list], list[Item]] | None = None,
    equal: dict | None = None,
) -> Page[Item]:
    """One page of ``query``'s entities (one kind, with an integer ``id``) in id order after
    ``cursor``, narrowed to rows whose column equals each ``equal`` value that is given
    (None: any). The page's items are ``item``s: ``out`` of the rows, by default each row
    validated as one. (The page is of the endpoint's declared type, so FastAPI need not
    validate it again.)"""
    entity = query.column_descriptions[0]["entity"]
    for column, value in (equal or {}).items():
        if value is not None:
            query = query.where(column == value)
    rows = session.scalars(
        query.where(entity.id > decode_cursor(cursor)).order_by(entity.id).limit(limit + 1)
    ).all()
    page = list(rows[:limit])
    items = out(page) if out is not None else [item.model_validate(r) for r in page]
    return Page[item](items=items, next_cursor=next_cursor(rows, limit))


def next_cursor(rows: Sequence, limit: int) -> str | None:
    """Given ``limit + 1`` rows fetched, the cursor for the page after ``rows[:limit]``."""
    return encode_cursor(rows[limit - 1].id) if len(rows) > limit else None
