"""The base of every request body the API reads."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field
from pydantic_core import PydanticCustomError

from supervisor.ids import MAX_ID

MAX_MM = 1e6
"""A kilometre: no coordinate or length the API keeps is larger."""
Millimetres = Annotated[float, Field(ge=-MAX_MM, le=MAX_MM)]


def _json_number(value: object) -> object:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise PydanticCustomError("int_type", "Input should be a valid integer")
    return value


RequestId = Annotated[int, Field(strict=False, ge=1, le=MAX_ID), BeforeValidator(_json_number)]
"""A row id in a request body: an integer as JSON Schema has it — 3 or 3.0, not 3.5, "3"
or true (a strict int would refuse 3.0, a lax one take "3" and true)."""


class RequestModel(BaseModel):
    """Unknown fields are refused, and so are numbers that are not finite: NaN, ±Infinity
    and literals beyond a double's range (``1e400``, which JSON parsers read as infinity)
    — each with a 422 naming the field, before anything is stored.

    Types are strict, as the schema states them: no ``"5"`` or ``true`` for a number, no
    ``1`` or ``"yes"`` for a boolean, no number for a string. (A field whose JSON value
    becomes another Python type — an array a tuple, a string a datetime — says
    ``strict=False``, and checks the JSON value first where lax parsing would take more
    than the schema allows: ``RequestId``, ``OfflineJudgment.client_time``.)"""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


def _no_default(schema: dict[str, Any]) -> None:
    schema.pop("default", None)


def omittable(**constraints: Any) -> Any:
    """A field that may be left out (it is None then) but not given as null: a PATCH's
    field that has no "empty" value."""
    return Field(None, json_schema_extra=_no_default, **constraints)
