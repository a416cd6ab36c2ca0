"""The package's house, read from its source with ``ast`` (nothing is imported).

- every module of every folder counts, named by its dotted path (``segment.refine``, ``cli``);
- no import cycle among the modules, nor among the folders (stages): every import counts, at
  module level, inside functions, under ``if TYPE_CHECKING:``, and
  ``importlib.import_module("annotate_rgbd.x")`` (written out or held in a module constant);
- the stages are layers: the geometry and the per-frame stage never import the run machinery,
  the CVAT reader or the report (:data:`FORBIDDEN`);
- only the command line (``cli/``, ``__main__.py``) imports typer, and no other module imports ``cli``;
- at most :data:`MAX_TOP_MODULES` modules directly in ``annotate_rgbd/``; none longer than 600 lines;
- only the CVAT reader and writer see XML;
- every third-party import is a runtime dependency of pyproject.toml (or the optional viewer).
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "annotate_rgbd"
PACKAGE_NAME = "annotate_rgbd"
COMMAND_LINE = {"cli", "__main__"}
MAX_LINES = 600
MAX_TOP_MODULES = 12

#: Stage -> the stages it must never import (directly): a stage only knows the ones below it.
LOW = {"errors", "logs", "progress", "pool", "config", "io", "geometry", "annotation"}
FORBIDDEN = {
    "io": {"config", "annotation", "cvat", "geometry", "segment", "propagate", "pipeline", "report", "review",
           "detect", "propose", "evaluate", "export"},
    "geometry": {"io", "cvat", "annotation", "segment", "propagate", "pipeline", "report", "review", "detect",
                 "propose", "evaluate", "export", "pool"},
    "cvat": {"geometry", "segment", "propagate", "pipeline", "report", "review", "detect", "propose", "evaluate",
             "export"},
    "segment": {"io", "cvat", "propagate", "pipeline", "report", "review", "detect", "propose", "evaluate", "export",
                "pool"},
    "propagate": {"cvat", "pipeline", "report", "review", "detect", "propose", "evaluate", "export"},
    "detect": {"io", "cvat", "segment", "propagate", "pipeline", "report", "review", "propose", "evaluate", "export"},
    "report": {"pipeline", "review", "propose", "detect", "evaluate", "export", "cvat"},
    "review": {"pipeline", "propose", "detect", "evaluate", "export", "cvat"},
    "pipeline": {"propose", "detect", "evaluate", "export"},
    "evaluate": {"segment", "propagate", "pipeline", "review", "propose", "detect", "export", "cvat"},
}


def module_names() -> list[str]:
    """Every module of the package, dotted from the package (``__init__`` for the package
    itself, ``segment`` for ``segment/__init__.py``)."""
    names = []
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(PACKAGE).with_suffix("").parts)
        if parts[-1] == "__init__" and len(parts) > 1:
            parts.pop()
        names.append(".".join(parts))
    return names


def module_path(name: str, root: Path = PACKAGE) -> Path:
    candidate = root / Path(*name.split(".")).with_suffix(".py")
    return candidate if candidate.exists() else root / Path(*name.split(".")) / "__init__.py"


def imported_modules(name: str, modules: set[str], root: Path = PACKAGE) -> tuple[set[str], set[str]]:
    """What module ``name`` imports.

    Returns
    -------
    internal : set of str
        The package's modules it imports (dotted as in :func:`module_names`; the longest known
        prefix of what it names, ``from x import y`` counting ``x.y`` when that is a module).
    external : set of str
        Top-level names of the other packages it imports (``typer``, ``numpy``...).
    """
    path = module_path(name, root)
    tree = ast.parse(path.read_text(encoding="utf-8"))
    is_package = path.name == "__init__.py"
    here = name.split(".") if name != "__init__" else []
    package = here if is_package else here[:-1]
    constants = {
        target.id: node.value.value
        for node in tree.body
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)
        for target in node.targets
        if isinstance(target, ast.Name)
    }
    internal: set[str] = set()
    external: set[str] = set()

    def known(parts: list[str]) -> str:
        for end in range(len(parts), 0, -1):
            if ".".join(parts[:end]) in modules:
                return ".".join(parts[:end])
        return "__init__"

    def add(parts: list[str], names: list[str]) -> None:
        found = False
        for leaf in names:
            dotted = ".".join([*parts, leaf])
            if dotted in modules:
                internal.add(dotted)
                found = True
        if not found or any(".".join([*parts, leaf]) not in modules for leaf in names):
            internal.add(known(parts))

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == PACKAGE_NAME:
                    internal.add(known(parts[1:]))
                else:
                    external.add(parts[0])
        elif isinstance(node, ast.ImportFrom):
            names = [a.name for a in node.names]
            if node.level == 0:
                parts = (node.module or "").split(".")
                if parts[0] != PACKAGE_NAME:
                    external.add(parts[0])
                    continue
                add(parts[1:], names)
            else:
                base = package[: len(package) - (node.level - 1)]
                add(base + (node.module.split(".") if node.module else []), names)
        elif isinstance(node, ast.Call) and _is_import_module(node.func) and node.args:
            argument = node.args[0]
            value = argument.value if isinstance(argument, ast.Constant) else constants.get(getattr(argument, "id", None))
            if isinstance(value, str) and value.split(".")[0] == PACKAGE_NAME:
                internal.add(known(value.split(".")[1:]))
            elif isinstance(value, str):
                external.add(value.split(".")[0])
    internal.discard(name)
    return internal, external


def _is_import_module(func: ast.expr) -> bool:
    """``importlib.import_module`` or a bare ``import_module``."""
    if isinstance(func, ast.Attribute):
        return func.attr == "import_module"
    return isinstance(func, ast.Name) and func.id == "import_module"


def import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports."""
    modules = set(module_names())
    return {name: imported_modules(name, modules)[0] for name in sorted(modules)}


def stage(module: str) -> str:
    """The folder (stage) a module belongs to; a top-level module is its own."""
    return module.split(".")[0]


def stage_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """Stage -> the other stages its modules import. The package's face (``__init__``) is left
    out: it names every command lazily, for users, and no module imports it but for the version."""
    stages: dict[str, set[str]] = {}
    for module, imported in graph.items():
        if module == "__init__":
            continue
        stages.setdefault(stage(module), set()).update(stage(m) for m in imported if m != "__init__")
    return {s: targets - {s} for s, targets in stages.items()}


def find_cycles(graph: dict[str, set[str]]) -> set[tuple[str, ...]]:
    """Every elementary cycle of ``graph``, each rotated to start at its smallest node.

    A depth-first search from each node ``s`` through nodes larger than ``s`` finds each cycle
    exactly once, from its smallest node (the package has a few dozen modules: plenty fast).
    """
    cycles = set()
    for start in sorted(graph):
        stack = [(start, [start])]
        while stack:
            node, path = stack.pop()
            for nxt in graph.get(node, ()):
                if nxt == start:
                    cycles.add(tuple(path))
                elif nxt > start and nxt not in path:
                    stack.append((nxt, path + [nxt]))
    return cycles


def describe(cycles) -> str:
    return "; ".join(" -> ".join(cycle + (cycle[0],)) for cycle in sorted(cycles)) or "none"


def test_find_cycles_finds_each_cycle_once():
    # Two cycles sharing a node, a self-import and an acyclic tail: checked by hand.
    graph = {"a": {"b"}, "b": {"c", "a"}, "c": {"a", "d"}, "d": set(), "e": {"e"}}
    assert find_cycles(graph) == {("a", "b"), ("a", "b", "c"), ("e",)}
    assert find_cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == set()


def test_imports_are_read_from_every_form(tmp_path):
    # Each import form of the package, in a throw-away sub-package: all of them must be seen.
    source = '''
import importlib
from typing import TYPE_CHECKING
import annotate_rgbd.m1
from annotate_rgbd import m2
from annotate_rgbd.sub import m9
from .. import m3, __version__
from ..m4 import thing
from .sibling import x
TARGET = "annotate_rgbd.m7"
if TYPE_CHECKING:
    from ..m5 import Hint
def later():
    from ..m6 import helper
    importlib.import_module(TARGET)
    importlib.import_module("annotate_rgbd.m8")
    import typer
'''
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "probe.py").write_text(source, encoding="utf-8")
    modules = {"sub", "sub.probe", "sub.sibling", "sub.m9"} | {f"m{i}" for i in range(1, 9)}
    internal, external = imported_modules("sub.probe", modules, tmp_path)
    assert internal == {f"m{i}" for i in range(1, 9)} | {"__init__", "sub.sibling", "sub.m9"}
    assert external == {"importlib", "typing", "typer"}


def test_the_walk_sees_every_folder():
    names = set(module_names())
    assert {"segment.refine", "cvat.reader", "pipeline.plan", "cli", "__init__", "geometry"} <= names
    assert len(names) == len(list(PACKAGE.rglob("*.py")))


def test_no_import_cycles():
    cycles = find_cycles(import_graph())
    assert not cycles, f"import cycles in annotate_rgbd: {describe(cycles)}"


def test_no_cycles_between_stages():
    cycles = find_cycles(stage_graph(import_graph()))
    assert not cycles, f"stages importing each other: {describe(cycles)}"


def test_no_stage_reaches_into_a_later_one():
    stages = stage_graph(import_graph())
    graph = import_graph()
    wrong = []
    for source, targets in sorted(stages.items()):
        for target in sorted(targets & FORBIDDEN.get(source, set())):
            where = sorted(m for m, imported in graph.items() if stage(m) == source and any(stage(i) == target for i in imported))
            wrong.append(f"{source} -> {target} ({', '.join(where)})")
    assert not wrong, "stages reaching into later ones: " + "; ".join(wrong)


def test_the_layer_check_sees_a_wrong_import(tmp_path):
    stages = stage_graph({"geometry.camera": {"pipeline.plan"}, "pipeline.plan": {"geometry.camera"}})
    assert stages["geometry"] & FORBIDDEN["geometry"] == {"pipeline"}


def test_command_line_is_the_top_layer():
    modules = set(module_names())
    for name in sorted(modules):
        internal, external = imported_modules(name, modules)
        if name.split(".")[0] not in COMMAND_LINE:
            assert "typer" not in external, f"{name} imports typer: only cli/ parses options"
            assert not any(m.split(".")[0] == "cli" for m in internal), \
                f"{name} imports cli: cli calls the library, never the reverse"


def test_few_modules_at_the_top():
    top = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(top) <= MAX_TOP_MODULES, f"{len(top)} modules directly in annotate_rgbd/: {top}; put them in a stage"


def test_module_length():
    lengths = {name: len(module_path(name).read_text(encoding="utf-8").splitlines()) for name in module_names()}
    long = {name: n for name, n in lengths.items() if n > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines, split them by job: " + ", ".join(
        f"{module_path(name).relative_to(PACKAGE.parent)} ({n} lines)" for name, n in sorted(long.items())
    )


def test_only_the_cvat_readers_and_writer_see_xml():
    """The CVAT format is read in one place: no other module imports an XML library."""
    allowed = {"cvat/xmlstream.py", "cvat/meta.py", "cvat/reader.py", "cvat/writer.py"}
    seeing = set()
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else (
                [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any(n.split(".")[0] in ("lxml", "xml", "defusedxml") for n in names):
                seeing.add(path.relative_to(PACKAGE).as_posix())
    assert seeing and seeing <= allowed, sorted(seeing - allowed)


#: The module each runtime distribution of pyproject.toml is imported as, where the names differ.
IMPORT_NAMES = {"opencv-python-headless": "cv2", "scikit-image": "skimage"}
#: Optional extras the package imports where they are used (the `viewer` extra: `review --rerun`).
OPTIONAL_IMPORTS = {"rerun"}


def pyproject() -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10: the tomli backport (a runtime dependency there)
        import tomli as tomllib

    return tomllib.loads((PACKAGE.parent / "pyproject.toml").read_text(encoding="utf-8"))


def runtime_imports() -> set[str]:
    """The top-level names of pyproject.toml's runtime dependencies, as the package imports them."""
    import re

    project = pyproject()["project"]
    names = {re.split(r"[<>=!~;\[ ]", requirement, maxsplit=1)[0].strip() for requirement in project["dependencies"]}
    return {IMPORT_NAMES.get(name, name.replace("-", "_")) for name in names}


def test_every_package_folder_is_installed():
    # pyproject.toml lists the packages a wheel (a non-editable install) holds: a folder missing
    # there imports in the editable checkout and fails in every installed copy.
    listed = set(pyproject()["tool"]["setuptools"]["packages"])
    folders = {".".join((PACKAGE_NAME, *path.parent.relative_to(PACKAGE).parts)) for path in PACKAGE.rglob("__init__.py")}
    assert folders - listed == set(), f"package folders missing from pyproject.toml's packages: {sorted(folders - listed)}"


def test_every_third_party_import_is_a_declared_dependency():
    # Open3D, for one, is only the real-data kit's (the `realdata` extra): the package must never need it.
    import sys

    declared = runtime_imports()
    assert {"numpy", "cv2", "skimage", "typer"} <= declared and "open3d" not in declared
    modules = set(module_names())
    undeclared = {}
    for name in sorted(modules):
        for external in imported_modules(name, modules)[1]:
            top = external.split(".")[0]
            if top not in sys.stdlib_module_names and top not in declared | OPTIONAL_IMPORTS:
                undeclared.setdefault(top, []).append(name)
    assert not undeclared, "imports of undeclared dependencies: " + "; ".join(
        f"{top} ({', '.join(names)})" for top, names in sorted(undeclared.items()))
