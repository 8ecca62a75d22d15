"""Row ids as the API accepts them: positive and within the database's integer column."""

from __future__ import annotations

from typing import Annotated

from fastapi import Path, Query
from pydantic import Field

MAX_ID = 2**31 - 1  # PostgreSQL `integer`; SQLite would take more, but ids must mean the same

IdPath = Annotated[int, Path(ge=1, le=MAX_ID)]
IdField = Annotated[int, Field(ge=1, le=MAX_ID)]


def IdQuery(description: str):  # noqa: ANN201 - reads like a type at the call site
    return Query(None, ge=1, le=MAX_ID, description=description)
