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


@pytest.fixture(scope="session")
def sample_run(tmp_path_factory):
    """``cvat2mask`` on the bundled sample with its camera.toml, made once for the whole test
    session: ``(output folder, SceneResult)``. Read it, never change it (copy it first)."""
    from annotate_rgbd.config.settings import load_config
    from annotate_rgbd.pipeline.scene import run_cvat2mask

    out = tmp_path_factory.mktemp("sample_run") / "out"
    result = run_cvat2mask(SAMPLE_DATA / "sequence", [SAMPLE_DATA / "annotations.xml"], out,
                           load_config(SAMPLE_DATA / "camera.toml"))
    return out, result
