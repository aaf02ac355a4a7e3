"""Every module is exercised by the fast tests (``-m "not slow"``), so a CI run that leaves the slow
cases out still covers every module (issue 23: the suite kept to ~10 minutes on 2 cores).

A module counts as exercised when a test file that has tests not marked ``slow`` imports it (at the
top, in a fixture or helper, or in one of its fast tests; the imports inside slow tests do not count),
when a command module's command is invoked by such a test (a list ``["NAME", ...]`` of arguments, as
``CliRunner().invoke(cli, ["NAME", ...])``, or a helper's call ``_cli("NAME", ...)``),
or when an exercised module imports it (lazy imports inside functions included: they run when the
function does).  Package ``__init__`` modules count with their submodules.  Built with :mod:`ast`
from the files: no import of the package, no test run.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

from test_layout import IMPORTS, MODULES

TESTS = Path(__file__).resolve().parent
MAIN = TESTS.parent / "src" / "lidarcat" / "cli" / "main.py"


def _slow(node: ast.AST) -> bool:
    return any(ast.unparse(d).endswith("mark.slow") for d in getattr(node, "decorator_list", ()))


def _file_is_slow(tree: ast.Module) -> bool:
    """``pytestmark = pytest.mark.slow`` (or a list holding it) at the top of the file."""
    return any(isinstance(n, ast.Assign) and any(getattr(t, "id", "") == "pytestmark" for t in n.targets)
               and re.search(r"\bmark\.slow\b", ast.unparse(n.value)) for n in tree.body)


def _commands() -> dict[str, str]:
    """Command name -> its module, from the table of ``lidarcat.cli.main`` (imported lazily by name)."""
    text = MAIN.read_text(encoding="utf-8")
    return {name: mod for name, mod in re.findall(r'\("([a-z-]+)", "(lidarcat\.cli\.[a-z_]+):', text)}


def fast_reach(tests: Path = TESTS) -> dict[str, str]:
    """Each module the fast tests exercise -> a test file that does (directly or through its importers)."""
    commands = _commands()
    reach: dict[str, str] = {}
    for f in sorted(tests.rglob("*.py")):
        tree = ast.parse(f.read_text(encoding="utf-8"), filename=str(f))
        if _file_is_slow(tree):
            continue
        funcs = [n for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
        tests_here = [n for n in funcs if n.name.startswith("test")]
        if f.name != "conftest.py" and (not tests_here or all(_slow(t) for t in tests_here)):
            continue
        skip = {id(x) for t in tests_here if _slow(t) for x in ast.walk(t)}
        where = str(f.relative_to(tests.parent))
        for n in ast.walk(tree):
            if id(n) in skip:
                continue
            names: list[str] = []
            if isinstance(n, ast.Import):
                names = [a.name for a in n.names]
            elif isinstance(n, ast.ImportFrom) and n.module and not n.level:
                names = [n.module, *(f"{n.module}.{a.name}" for a in n.names)]
            elif isinstance(n, ast.List) and n.elts and isinstance(n.elts[0], ast.Constant):
                names = [commands.get(str(n.elts[0].value), "")]       # ["chart", MOSAIC, ...]: arguments
            elif isinstance(n, ast.Call) and re.search(r"cli|invoke", ast.unparse(n.func), re.I) and n.args \
                    and isinstance(n.args[0], ast.Constant):
                names = [commands.get(str(n.args[0].value), "")]       # _cli("convert", ...): a helper's call
            for m in names:
                parts = m.split(".")
                for k in range(1, len(parts) + 1):   # a module and the packages it is in
                    if ".".join(parts[:k]) in MODULES:
                        reach.setdefault(".".join(parts[:k]), where)
    graph: dict[str, set[str]] = {}
    for importer, imported, _name, _path, _line in IMPORTS:
        graph.setdefault(importer, set()).add(imported)
    todo = list(reach)
    while todo:
        m = todo.pop()
        for dep in graph.get(m, ()):
            parts = dep.split(".")
            for k in range(1, len(parts) + 1):
                p = ".".join(parts[:k])
                if p in MODULES and p not in reach:
                    reach[p] = reach[m]
                    todo.append(p)
    return reach


def test_every_module_is_exercised_by_a_fast_test():
    reach = fast_reach()
    missing = sorted(m for m in MODULES if m not in reach)
    assert not missing, ("modules no fast test reaches (give each a test not marked slow): "
                         + ", ".join(missing))


def test_a_module_only_a_slow_test_imports_is_found(tmp_path):
    """The check itself: a slow test's import does not count, a fast test's does."""
    (tmp_path / "test_a.py").write_text(
        "import pytest\n\n\n@pytest.mark.slow\ndef test_slow():\n    from lidarcat.bundle import selfcal\n\n\n"
        "def test_fast():\n    pass\n")
    assert "lidarcat.bundle.selfcal" not in fast_reach(tmp_path)
    (tmp_path / "test_b.py").write_text("def test_fast():\n    from lidarcat.bundle import selfcal\n")
    assert fast_reach(tmp_path)["lidarcat.bundle.selfcal"] == f"{tmp_path.name}/test_b.py"
