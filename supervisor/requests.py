"""The base of every request body the API reads."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

MAX_MM = 1e6
"""A kilometre: no coordinate or length the API keeps is larger."""
Millimetres = Annotated[float, Field(ge=-MAX_MM, le=MAX_MM)]


class RequestModel(BaseModel):
    """Unknown fields are refused, and so are numbers that are not finite: NaN, ±Infinity
    and literals beyond a double's range (``1e400``, which JSON parsers read as infinity)
    — each with a 422 naming the field, before anything is stored."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
