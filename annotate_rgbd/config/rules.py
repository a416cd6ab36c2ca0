"""The one-line range rules of the configuration sections that check themselves on creation."""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable, Iterable


def check_section(section: str, values: Any, rules: Iterable[tuple[str, Callable[[Any], bool], str]]) -> None:
    """Check a configuration section's values: numbers finite, integers whole, then ``rules``.

    Parameters
    ----------
    section : str
        The section's name in a configuration file (``detect``...), for the messages.
    values : dataclass instance
        The section.
    rules : iterable of (str, callable, str)
        ``(key, test, rule)``: ``test(value)`` tells whether the key's value keeps the rule,
        worded as in ``"must be > 0"``. Tested after the type checks, in order; the first
        failure is reported.

    Raises
    ------
    ValueError
        One line naming ``section.key``: ``'detect.cell_px' must be an integer >= 2, got 1``. The
        configuration loader turns it into an ``InputError`` naming the file or option.
    """
    for item in dataclasses.fields(values):
        value = getattr(values, item.name)
        key = f"'{section}.{item.name}'"
        if item.type in ("int", int) and (isinstance(value, bool) or not isinstance(value, int)):
            raise ValueError(f"{key} must be an integer, got {value!r}")
        if item.type in ("str", str) and not isinstance(value, str):
            raise ValueError(f"{key} must be a string, got {value!r}")
        if item.type in ("float", float):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"{key} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"{key} must be a finite number, got {value!r}")
    for name, test, rule in rules:
        if not test(getattr(values, name)):
            raise ValueError(f"'{section}.{name}' {rule}, got {getattr(values, name)!r}")
