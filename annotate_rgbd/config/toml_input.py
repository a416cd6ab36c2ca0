"""Reading TOML text (configurations, manifests, ``--set`` values) with one-line errors."""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import Any

from annotate_rgbd.errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib


#: Deepest nesting of tables and arrays accepted in a configuration, manifest or ``--set``
#: value (ours need 3 levels; tomllib itself recurses and would fail at ~1000 with a traceback).
MAX_TOML_NESTING = 16


class NestedTooDeep(InputError):
    """TOML text with tables and arrays nested more than :data:`MAX_TOML_NESTING` deep."""

    def __init__(self, path: str | Path | None):
        super().__init__(path, f"invalid TOML: values nested more than {MAX_TOML_NESTING} levels deep")


def read_toml(text: str, origin: str | Path | None) -> dict[str, Any]:
    """Parse TOML text (a configuration, a manifest, a ``--set`` value).

    Raises
    ------
    InputError
        Invalid TOML (:class:`NestedTooDeep`: tables and arrays nested more than
        :data:`MAX_TOML_NESTING` deep).
    """
    # Arrays and inline tables opened before any is closed bound the depth tomllib recurses to.
    if _bracket_depth(text) > MAX_TOML_NESTING:
        raise NestedTooDeep(origin)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(origin, f"invalid TOML: {exc}") from None
    except RecursionError:
        raise NestedTooDeep(origin) from None


def _bracket_depth(text: str) -> int:
    """The deepest nesting of ``[``/``{`` in ``text``, outside strings and comments (roughly:
    an over-estimate only ever rejects a pathological file)."""
    depth = deepest = 0
    for bracket in _BRACKETS.findall(_STRINGS_AND_COMMENTS.sub("", text)):
        depth += 1 if bracket in "[{" else -1
        deepest = max(deepest, depth)
    return deepest


_STRINGS_AND_COMMENTS = re.compile(r'"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*')
_BRACKETS = re.compile(r"[\[\]{}]")
