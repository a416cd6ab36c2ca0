"""The README is a short guide: its quick start is what CI runs, and every link of it and of the
pages in docs/ leads somewhere."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: The README's two quick-start commands, exactly (a newcomer copies them; CI runs the second).
SETUP_AND_SAMPLE = ("bash .ci/setup && .venv/bin/annotate-rgbd cvat2mask sample_data/sequence sample_data/annotations.xml "
                    "--config sample_data/camera.toml --out out/sample")
TESTS = "bash .ci/setup --tests && .venv/bin/python -m pytest"
MAX_LINES = 250

LINK = re.compile(r"\]\(([^)\s]+)\)")


def _code_lines(text: str) -> list[str]:
    """The indented code lines of a Markdown text, without their indent."""
    return [line[4:] for line in text.splitlines() if line.startswith("    ") and not line.startswith("     ")]


def _slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation but '-' and '_' dropped, spaces -> '-'."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    """The anchors of a page's headings (outside fenced code, where '#' starts a comment)."""
    anchors, fenced = set(), False
    for line in path.read_text(encoding="utf-8").splitlines():
        fenced ^= line.startswith("```")
        if not fenced and re.match(r"#{1,6} ", line):
            anchors.add(_slug(line.lstrip("#")))
    return anchors


def _pages() -> list[Path]:
    return [README, *sorted((ROOT / "docs").glob("*.md"))]


def test_the_readme_is_a_short_guide():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= MAX_LINES, f"README.md has {len(lines)} lines: move reference material to docs/"


def test_the_quick_start_commands_are_the_readmes_and_ci_runs_the_test_command():
    commands = _code_lines(README.read_text(encoding="utf-8"))
    assert commands[:2] == [SETUP_AND_SAMPLE, TESTS]
    ci = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if line and not line.startswith("#")]
    assert ci[-1].endswith(TESTS), "CI must run the README's test command"


def test_every_link_of_the_readme_and_the_docs_leads_somewhere():
    checked = 0
    for page in _pages():
        for target in LINK.findall(page.read_text(encoding="utf-8")):
            if target.startswith(("http://", "https://")):
                continue
            path, _, anchor = target.partition("#")
            resolved = (page.parent / path).resolve() if path else page
            assert resolved.exists(), f"{page.relative_to(ROOT)}: link to {target}: no such file"
            if anchor:
                assert anchor in _anchors(resolved), f"{page.relative_to(ROOT)}: link to {target}: no such heading"
            checked += 1
    assert checked > 50


def test_every_docs_page_is_linked_from_the_readme():
    linked = {(ROOT / target.partition("#")[0]).resolve() for target in LINK.findall(README.read_text(encoding="utf-8"))}
    for page in sorted((ROOT / "docs").glob("*.md")):
        assert page.resolve() in linked, f"{page.relative_to(ROOT)} is not linked from README.md"


def test_the_slug_is_githubs():
    assert _slug(" `[colour_camera]`") == "colour_camera"
    assert _slug(" Another round: `export-cvat`") == "another-round-export-cvat"
    assert _slug(" `[stitch]`, `[[parts]]`, `[[matches]]`") == "stitch-parts-matches"
