"""The house by stage (issue 23): the layout rules, checked on the source itself.

* only ``__init__``, ``errors`` and ``testing`` are modules at the top of the package;
* the import graph has no circle -- every ``import`` counts, the lazy ones inside
  functions too (a lazy import hides a circle from Python, not from a reader);
* a ``_name`` is never imported from another module (``from .x import _y``);
  a private *module* (``_util``, ``lidar/_las.py``) is the way to share helpers;
* the engine knows no survey folder: ``lidarcat.bundle`` never imports
  ``lidarcat.survey``, and the tile engine (``lidarcat.lidar.jobs``) no product.

The graph is built with :mod:`ast` from the files, so the test needs no import
of the package and names the file and line of every offending import.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PKG = SRC / "lidarcat"


def _modules() -> dict[str, tuple[Path, bool]]:
    mods = {}
    for p in sorted(PKG.rglob("*.py")):
        parts = list(p.relative_to(SRC).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        if is_pkg:
            parts = parts[:-1]
        mods[".".join(parts)] = (p, is_pkg)
    return mods


MODULES = _modules()


def _imports() -> list[tuple[str, str, str | None, Path, int]]:
    """Every import of a lidarcat module: (importer, imported module, imported name or None, file, line)."""
    out = []
    for mod, (path, is_pkg) in MODULES.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name in MODULES:
                        out.append((mod, a.name, None, path, node.lineno))
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                    base = base[:len(base) - (node.level - 1)]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if target not in MODULES:
                    continue
                for a in node.names:
                    sub = f"{target}.{a.name}"
                    if sub in MODULES:
                        out.append((mod, sub, None, path, node.lineno))
                    else:
                        out.append((mod, target, a.name, path, node.lineno))
    return out


IMPORTS = _imports()


def _where(path: Path, line: int) -> str:
    return f"{path.relative_to(SRC.parent)}:{line}"


def test_only_init_errors_testing_at_the_top():
    top = sorted(p.stem for p in PKG.glob("*.py"))
    assert top == ["__init__", "errors", "testing"], top


def test_the_import_graph_has_no_circle():
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for importer, target, _name, _path, _line in IMPORTS:
        if importer != target:
            graph[importer].add(target)
    # Tarjan's strongly connected components, iteratively
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        circles.append(sorted(comp))
    assert not circles, "import circles:\n" + "\n".join(" <-> ".join(c) for c in circles)


def test_no_private_name_is_imported_from_another_module():
    bad = [f"{_where(p, line)}: {name} from {target}"
           for importer, target, name, p, line in IMPORTS
           if name and name.startswith("_") and not name.startswith("__") and target != importer]
    assert not bad, "private names imported across modules:\n" + "\n".join(bad)


@pytest.mark.parametrize("engine, forbidden", [
    ("lidarcat.bundle", "lidarcat.survey"),
    ("lidarcat.bundle", "lidarcat.stages"),
    ("lidarcat.lidar", "lidarcat.production"),
    ("lidarcat.lidar", "lidarcat.control"),
    ("lidarcat.geometry", "lidarcat.survey"),
    ("lidarcat.stages", "lidarcat.pipeline"),
    ("lidarcat.stages", "lidarcat.cli"),
    ("lidarcat.photocontrol", "lidarcat.survey"),
    ("lidarcat.photocontrol", "lidarcat.stages"),
    ("lidarcat.photocontrol", "lidarcat.cli"),
    ("lidarcat.photocontrol", "lidarcat.synthetic"),
])
def test_dependencies_point_one_way(engine, forbidden):
    bad = [f"{_where(p, line)}: {importer} imports {target}"
           for importer, target, _name, p, line in IMPORTS
           if (importer == engine or importer.startswith(engine + "."))
           and (target == forbidden or target.startswith(forbidden + "."))]
    assert not bad, "\n".join(bad)
