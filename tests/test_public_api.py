"""The package's public face: a curated, lazily loaded ``__all__`` and the documented import paths."""

from __future__ import annotations

import subprocess
import sys

import annotate_rgbd


def test_every_public_name_loads_and_is_what_its_module_defines():
    from annotate_rgbd.config.settings import Config, load_config
    from annotate_rgbd.errors import InputError, OutputError
    from annotate_rgbd.pipeline.batch import run_batch
    from annotate_rgbd.pipeline.scene import run_cvat2mask

    assert set(annotate_rgbd.__all__) >= {"run_cvat2mask", "run_batch", "run_propose", "review_run", "export_cvat",
                                          "evaluate_paths", "load_config", "InputError", "OutputError"}
    for name in annotate_rgbd.__all__:
        assert getattr(annotate_rgbd, name) is not None
    assert annotate_rgbd.run_cvat2mask is run_cvat2mask and annotate_rgbd.run_batch is run_batch
    assert annotate_rgbd.load_config is load_config and annotate_rgbd.Config is Config
    assert annotate_rgbd.InputError is InputError and annotate_rgbd.OutputError is OutputError
    assert "run_cvat2mask" in dir(annotate_rgbd)


def test_the_readmes_import_paths_work():
    from annotate_rgbd.config import load_config
    from annotate_rgbd.pipeline import run_cvat2mask

    assert load_config is annotate_rgbd.load_config and run_cvat2mask is annotate_rgbd.run_cvat2mask


def test_importing_the_package_loads_no_stage():
    code = "import sys, annotate_rgbd; print(sorted(m for m in sys.modules if m.startswith('annotate_rgbd')))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "['annotate_rgbd']"


def test_an_unknown_name_is_an_attribute_error():
    try:
        annotate_rgbd.no_such_thing
    except AttributeError as exc:
        assert "no_such_thing" in str(exc)
    else:
        raise AssertionError("expected AttributeError")
