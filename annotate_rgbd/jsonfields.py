"""Typed fields out of JSON documents: the checks every record's ``from_json`` makes.

Each function returns the field or raises :class:`RecordError` with one line naming the field;
the readers of ``report.json``, the journal and the shapes record turn it into an ``error:``
line naming the file.
"""

from __future__ import annotations

from typing import Any


class RecordError(ValueError):
    """A JSON document does not have the layout of a record (wrong type, key missing)."""


def mapping(value: Any, what: str) -> dict:
    if not isinstance(value, dict):
        raise RecordError(f"{what} is not an object")
    return value


def list_field(entry: dict, key: str) -> list:
    value = entry.get(key)
    if not isinstance(value, list):
        raise RecordError(f"{key} is not a list")
    return value


def int_field(entry: dict, key: str) -> int:
    value = entry.get(key)
    if isinstance(value, bool) or not isinstance(value, int):
        raise RecordError(f"{key} is not an integer")
    return value


def optional_int(entry: dict, key: str) -> int | None:
    return None if entry.get(key) is None else int_field(entry, key)


def number(entry: dict, key: str, optional: bool = False) -> float | None:
    value = entry.get(key)
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise RecordError(f"{key} is not a number")
    return value


def numbers(values: Any, key: str, count: int) -> list[float]:
    if not isinstance(values, list) or len(values) != count:
        raise RecordError(f"{key} is not a list of {count} numbers")
    return [number({key: v}, key) for v in values]


def text(entry: dict, key: str, optional: bool = False) -> str | None:
    value = entry.get(key)
    if value is None and optional:
        return None
    if not isinstance(value, str):
        raise RecordError(f"{key} is not a string")
    return value
