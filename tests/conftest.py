"""Shared fixtures: the repository's paths and the optional real reference data."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
SAMPLE_DATA = REPO_ROOT / "sample_data"
#: Real public files beside the repository (absent in a user's clone).
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"


def reference_data(folder: str = "") -> Path:
    """A folder of the project's real reference files (``../shared/data/<folder>``), or skip.

    These files sit beside the development repository only (a user's clone does not have
    them): the tests that use them are optional checks on real data, skipped elsewhere.
    """
    path = SHARED_DATA / folder
    if not path.is_dir():
        pytest.skip(f"optional reference-data check: needs the project's real files in {path} "
                    "(beside the development repository, not in a user's clone)")
    return path


@pytest.fixture
def shared_data() -> Path:
    """The real reference data folder; the test is skipped where it is absent."""
    return reference_data()
