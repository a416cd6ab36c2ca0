"""Digest of everything the tool writes on fixed inputs: run before and after a refactoring.

Run from the repository root (the package must be installed)::

    python benchmarks/output_digest.py --save before.json      # on the old code
    python benchmarks/output_digest.py --compare before.json   # on the new code: exit 1 if any differ

It regenerates the committed sample (``sample_data/make_sample_data.py``) into a temporary folder
and compares it with ``sample_data/``, renders the benchmark's synthetic room at a small size, and
runs ``cvat2mask`` (1 and 2 workers) on the single and the two-part sample and on the benchmark
scene, with raw masks and overlays, then ``review`` and ``stats``. Every output file is hashed
(BLAKE2b); in ``report.json`` the absolute paths of the inputs are replaced by their path relative
to the temporary folder or the repository, so that digests taken in two clones compare equal.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _digest_tree(folder: Path, replace: dict[str, str]) -> dict[str, str]:
    digests = {}
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        data = path.read_bytes()
        if path.suffix in (".json", ".html", ".csv", ".txt", ".xml"):
            text = data.decode("utf-8")
            for old, new in replace.items():
                text = text.replace(old, new)
            data = text.encode("utf-8")
        digests[str(path.relative_to(folder))] = hashlib.blake2b(data, digest_size=16).hexdigest()
    return digests


def _cli(*args: str) -> str:
    done = subprocess.run([sys.executable, "-m", "annotate_rgbd", *args], capture_output=True, text=True)
    if done.returncode not in (0, 1):
        raise SystemExit(f"annotate-rgbd {' '.join(args)} failed ({done.returncode}): {done.stderr.strip()}")
    return f"exit {done.returncode}\n{done.stdout}"


def collect(work: Path) -> dict[str, dict[str, str]]:
    """Produce every output into ``work`` and return their digests by run."""
    replace = {str(work): "<work>", str(ROOT): "<repo>"}
    result: dict[str, dict[str, str]] = {}

    sample = work / "sample"
    subprocess.run([sys.executable, str(ROOT / "sample_data" / "make_sample_data.py"), str(sample)], check=True,
                   capture_output=True)
    made, committed = _digest_tree(sample, {}), _digest_tree(ROOT / "sample_data", {})
    result["sample_regenerated"] = {
        name: "same" if committed.get(name) == digest else "differs" for name, digest in made.items()
    }

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from bench_cvat2mask import make_benchmark_sequence  # noqa: E402

    bench_seq, bench_xml, camera = make_benchmark_sequence(work / "bench", 24, 320, 240)
    result["bench_scene"] = _digest_tree(work / "bench", replace)
    bench_cfg = work / "bench_camera.toml"
    bench_cfg.write_text(
        f"[camera]\nfx = {camera.fx}\nfy = {camera.fy}\ncx = {camera.cx}\ncy = {camera.cy}\n"
        f"depth_scale = {camera.depth_scale}\n", encoding="utf-8")

    seq, cfg = str(ROOT / "sample_data" / "sequence"), str(ROOT / "sample_data" / "camera.toml")
    parts = [str(ROOT / "sample_data" / "parts" / n) for n in ("0-11.xml", "9-18.xml")]
    runs = {
        "single": [seq, str(ROOT / "sample_data" / "annotations.xml"), "--config", cfg],
        "parts": [seq, *parts, "--config", cfg],
        "bench": [str(bench_seq), str(bench_xml), "--config", str(bench_cfg)],
    }
    for name, args in runs.items():
        for workers in (1, 2):
            out = work / f"out_{name}_{workers}"
            log = _cli("cvat2mask", *args, "--out", str(out), "--jobs", str(workers), "--raw-masks", "--overlays")
            log += _cli("cvat2mask", *args, "--out", str(out), "--jobs", str(workers), "--raw-masks", "--overlays")
            log += _cli("stats", str(out)) + _cli("stats", str(out), "--json")
            (out / "stats_and_log.txt").write_text(log, encoding="utf-8")
            result[f"{name}_{workers}"] = _digest_tree(out, replace)
            review = work / f"review_{name}_{workers}"
            _cli("cvat2mask", *args, "--out", str(review), "--jobs", str(workers))
            _cli("review", str(review))
            result[f"review_{name}_{workers}"] = _digest_tree(review, replace)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--save", type=Path, help="write the digests to this JSON file")
    group.add_argument("--compare", type=Path, help="compare with digests saved earlier")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        digests = collect(Path(tmp))
    files = sum(len(v) for v in digests.values())
    if args.save:
        args.save.write_text(json.dumps(digests, indent=1, sort_keys=True) + "\n", encoding="utf-8")
        print(f"{files} files digested -> {args.save}")
        return 0
    before = json.loads(args.compare.read_text(encoding="utf-8"))
    differences = [
        f"{run}/{name}: {'missing' if name not in digests.get(run, {}) else 'new' if name not in before.get(run, {}) else 'differs'}"
        for run in sorted(set(before) | set(digests))
        for name in sorted(set(before.get(run, {})) | set(digests.get(run, {})))
        if before.get(run, {}).get(name) != digests.get(run, {}).get(name)
    ]
    for line in differences:
        print(line)
    print(f"{files} files compared: {len(differences)} differ")
    return 1 if differences else 0


if __name__ == "__main__":
    sys.exit(main())
