"""The algorithm digest: a code change in the per-frame stage makes a re-run redo its frames.

Every change is made on a copy of the package (never on the package's own files).
"""

from __future__ import annotations

import ast
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from annotate_rgbd.config.settings import load_config
from annotate_rgbd.pipeline import resume
from annotate_rgbd.pipeline.execute import FrameCounts
from annotate_rgbd.pipeline.resume import MASK_CODE, NOT_MASK_CODE, PACKAGE, algorithm_digest
from annotate_rgbd.pipeline.scene import run_cvat2mask

from conftest import SAMPLE_DATA


def copy_package(tmp_path: Path) -> Path:
    """A copy of the package (its ``annotate_rgbd`` folder) under ``tmp_path``."""
    copy = tmp_path / "copy" / "annotate_rgbd"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    return copy


def flip_one_byte(path: Path, offset: int | None = None) -> None:
    """Change one byte of a module's source: a space in a comment or a docstring becomes '_'."""
    data = bytearray(path.read_bytes())
    offset = data.index(b" ", data.index(b'"""') + 3) if offset is None else offset
    data[offset] = ord("_")
    path.write_bytes(bytes(data))


def test_one_byte_in_any_mask_module_changes_the_digest(tmp_path):
    copy = copy_package(tmp_path)
    original = algorithm_digest(copy)
    assert original == algorithm_digest()  # the same in any copy of the package
    for module in ("segment/refine.py", "geometry/noise.py", "report/palette.py", "pipeline/frame_job.py"):
        saved = (copy / module).read_bytes()
        flip_one_byte(copy / module)
        algorithm_digest.cache_clear()
        assert algorithm_digest(copy) != original, module
        (copy / module).write_bytes(saved)
    algorithm_digest.cache_clear()
    assert algorithm_digest(copy) == original
    # A new module in a listed folder counts; a change outside the listed code does not.
    (copy / "segment" / "extra.py").write_text("X = 1\n")
    algorithm_digest.cache_clear()
    assert algorithm_digest(copy) != original
    (copy / "segment" / "extra.py").unlink()
    flip_one_byte(copy / "cvat" / "reader.py")
    algorithm_digest.cache_clear()
    assert algorithm_digest(copy) == original


def _imports(path: Path, package: Path) -> set[Path]:
    """The package's modules ``path`` imports (at any level of the file, relative or absolute)."""
    found = set()
    here = path.relative_to(package).parent
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        names = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = ".".join(("annotate_rgbd", *here.parts[: len(here.parts) - node.level + 1]))
                module = f"{base}.{node.module}" if node.module else base
            else:
                module = node.module or ""
            names = [module] + [f"{module}.{alias.name}" for alias in node.names]
        for name in names:
            if not name.startswith("annotate_rgbd."):
                continue
            relative = Path(*name.split(".")[1:])
            for candidate in (package / relative.with_suffix(".py"), package / relative / "__init__.py"):
                if candidate.is_file():
                    found.add(candidate)
            if name.count(".") >= 2:  # every package on the way is imported too
                parent = package / Path(*name.split(".")[1:-1]) / "__init__.py"
                if parent.is_file():
                    found.add(parent)
    return found


def test_every_module_the_frame_job_imports_is_in_the_digest_or_left_out_on_purpose():
    for part in MASK_CODE + NOT_MASK_CODE:
        assert (PACKAGE / part).exists(), f"{part} is listed but does not exist"
    def in_digest(name: str) -> bool:
        return name in MASK_CODE or any(name.startswith(f"{part}/") for part in MASK_CODE)

    # What the frame job runs: the modules that mask code imports, followed from the frame job
    # (a module left out on purpose is not followed: the __init__ files only re-export).
    seen, todo = set(), [PACKAGE / "pipeline" / "frame_job.py"]
    while todo:
        path = todo.pop()
        name = path.relative_to(PACKAGE).as_posix()
        if name not in seen:
            seen.add(name)
            todo += _imports(path, PACKAGE) if in_digest(name) else []
    assert {"segment/refine.py", "segment/ransac.py", "geometry/noise.py", "review/overlay.py"} <= seen
    unaccounted = sorted(n for n in seen if not in_digest(n) and n not in NOT_MASK_CODE)
    assert unaccounted == [], f"add these to resume.MASK_CODE (or, if they cannot change a frame's files, NOT_MASK_CODE): {unaccounted}"


def test_the_fingerprint_changes_with_the_digest(monkeypatch):
    from annotate_rgbd.annotation.model import Shape
    import numpy as np

    shapes = [(1, Shape("polygon", np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])))]
    config = load_config()
    before = resume.fingerprint(shapes, (8, 8), config, b"depth")
    monkeypatch.setattr(resume, "algorithm_digest", lambda: "another algorithm")
    assert resume.fingerprint(shapes, (8, 8), config, b"depth") != before


RERUN = """
import json, sys
from pathlib import Path
import annotate_rgbd
assert Path(annotate_rgbd.__file__).resolve().parent == Path(sys.argv[1]).resolve(), annotate_rgbd.__file__
from annotate_rgbd.config.settings import load_config
from annotate_rgbd.pipeline.scene import run_cvat2mask
report = run_cvat2mask(sys.argv[2], [sys.argv[3]], sys.argv[4], load_config(sys.argv[5]))
print(json.dumps([report.counts.made, report.counts.reused]))
"""


def test_a_rerun_after_a_code_change_in_refinement_redoes_every_frame(tmp_path):
    sequence, annotations, camera = SAMPLE_DATA / "sequence", SAMPLE_DATA / "annotations.xml", SAMPLE_DATA / "camera.toml"
    out = tmp_path / "out"
    first = run_cvat2mask(sequence, [annotations], out, load_config(camera))
    assert first.counts == FrameCounts(made=19, reused=0, failed=0)
    masks = {p.name: p.read_bytes() for p in (out / "masks").iterdir()}
    # The same run by a copy of the package whose refinement differs by one byte of a comment.
    copy = copy_package(tmp_path)
    flip_one_byte(copy / "segment" / "refine.py")
    env = {**os.environ, "PYTHONPATH": str(copy.parent)}
    done = subprocess.run([sys.executable, "-c", RERUN, str(copy), str(sequence), str(annotations), str(out),
                           str(camera)], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.splitlines()[-1]) == [19, 0]
    # Made anew, and (a comment changed) to the same bytes.
    assert {p.name: p.read_bytes() for p in (out / "masks").iterdir()} == masks
    # And this package again: the fingerprints differ from the copy's, so every frame once more.
    again = run_cvat2mask(sequence, [annotations], out, load_config(camera))
    assert again.counts == FrameCounts(made=19, reused=0, failed=0)


@pytest.mark.parametrize("setting, message", [
    ("refine.coherence_window=4", "'refine.coherence_window' must be 0 (no window test) or odd in [3, 51]"),
    ("refine.coherence_limit=0", "'refine.coherence_limit' must be in (0, 100]"),
    ("refine.min_inlier_density=1.5", "'refine.min_inlier_density' must be in [0, 1]"),
    ("refine.core_refits=-1", "'refine.core_refits' must be in [0, 20]"),
    ("ransac.band_share=0", "'ransac.band_share' must be in (0, 1]"),
    ("ransac.max_noise_scale=0.5", "'ransac.max_noise_scale' must be >= 1"),
    ("ransac.max_behind=-1", "'ransac.max_behind' must be in [0, 10]"),
    ("ransac.min_behind_points=2.5", "'ransac.min_behind_points' must be an integer, got 2.5"),
    ("propagate.same_surface_angle=91", "'propagate.same_surface_angle' must be in [0, 90] (degrees)"),
    ("propagate.beyond_reach=nan", "'propagate.beyond_reach' must be"),
    ("propagate.border_margin=-1", "'propagate.border_margin' must be >= 0"),
    ("propagate.time_offset_step=1e-9", "'propagate.time_offset_step' must be in [0.001, 1] s"),
    ("propagate.sideways=1", "unknown key 'propagate.sideways' (known in [propagate]: same_surface_angle,"),
])
def test_bad_tunables_are_one_line_errors(setting, message, tmp_path):
    from typer.testing import CliRunner

    from annotate_rgbd.cli import app

    result = CliRunner().invoke(app, ["cvat2mask", str(SAMPLE_DATA / "sequence"), str(SAMPLE_DATA / "annotations.xml"),
                                      "--out", str(tmp_path / "out"), "--set", setting])
    assert result.exit_code == 1, result.output
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], result.output
    assert not (tmp_path / "out" / "masks").exists()


def test_tunables_are_read_from_toml_and_set_and_reach_refinement(tmp_path):
    config_file = tmp_path / "tuned.toml"
    config_file.write_text("[refine]\ncoherence_limit = 3\n[ransac]\nband_share = 0.4\n[propagate]\nbeyond_reach = 0.25\n")
    config = load_config(config_file, {"refine.core_refits": 1, "ransac.max_behind": 0})
    assert config.refine.coherence_limit == 3.0 and isinstance(config.refine.coherence_limit, float)
    assert (config.ransac.band_share, config.ransac.max_behind) == (0.4, 0)
    assert (config.refine.core_refits, config.propagate.beyond_reach) == (1, 0.25)
    # The fingerprint keys on them.
    from annotate_rgbd.annotation.model import Shape
    import numpy as np

    shapes = [(1, Shape("polygon", np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])))]
    prints = {resume.fingerprint(shapes, (8, 8), c, b"depth") for c in (
        load_config(), load_config(None, {"refine.coherence_limit": 3}), load_config(None, {"ransac.band_share": 0.4}),
        load_config(None, {"propagate.same_surface_angle": 4})
    )}
    assert len(prints) == 4
