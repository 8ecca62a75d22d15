"""Counts in sentences for people: "1 junction", "2 junctions", "no defects"."""

from __future__ import annotations


def counted(count: int, noun: str, plural: str | None = None) -> str:
    """``count`` and ``noun``, in the plural unless it is one."""
    return f"{count} {noun if count == 1 else plural or noun + 's'}"
