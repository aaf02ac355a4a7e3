"""Docs cannot rot: the CLI reference is generated and in sync, links resolve, the notebook runs."""

from __future__ import annotations

import importlib
import pkgutil
import re

import click
import pytest
from conftest import ROOT

from lidarcat.cli.docs import iter_commands, render_cli_reference

DOCS = ROOT / "docs"
CLI_MD = DOCS / "cli.md"
REGEN = "regenerate it with `python -m lidarcat.cli.docs` (or python tools/gen_cli_docs.py)"


def _sections(text: str) -> dict[str, str]:
    parts = re.split(r"^## (.+)$", text, flags=re.M)
    return {parts[i].strip(): parts[i + 1] for i in range(1, len(parts) - 1, 2)}


def test_cli_reference_is_in_sync():
    assert CLI_MD.is_file(), f"docs/cli.md is missing; {REGEN}"
    assert CLI_MD.read_text(encoding="utf-8") == render_cli_reference(), f"docs/cli.md is stale; {REGEN}"


def test_every_command_and_option_is_documented():
    sections = _sections(CLI_MD.read_text(encoding="utf-8"))
    names = []
    for full, cmd, ctx in iter_commands():
        names.append(full)
        assert "(unavailable:" not in (cmd.help or ""), f"{full} could not be imported"
        assert full in sections, f"command {full!r} is not documented in docs/cli.md; {REGEN}"
        body = sections[full]
        for param in cmd.get_params(ctx):
            if isinstance(param, click.Option) and not param.hidden:
                for opt in (*param.opts, *param.secondary_opts):
                    assert opt in body, f"{full}: option {opt} is undocumented; {REGEN}"
            elif isinstance(param, click.Argument):
                assert param.make_metavar(ctx).strip("[].") in body, f"{full}: argument {param.name}"
        if not isinstance(cmd, click.Group):
            assert (cmd.help or "").strip(), f"{full} has no help text"
    for name in ("camera", "lidar", "extract", "adjust", "assess", "run", "demo"):
        assert f"lidarcat {name}" in names
    assert "lidarcat demo synthetic" in names


def test_generator_detects_a_missing_option(monkeypatch):
    """The sync test can fail: a new option changes the rendered reference."""
    from lidarcat.cli.run import run

    before = render_cli_reference()
    monkeypatch.setattr(run, "params", [*run.params, click.Option(["--brand-new-option"], help="x")])
    after = render_cli_reference()
    assert "--brand-new-option" in after and after != before


@pytest.mark.parametrize("page", ["index.md", "method.md", "cli.md", "figures.md", "survey-format.md",
                                  "accuracy.md", "extraction.md", "layout.md", "../README.md"])
def test_doc_pages_exist_and_links_resolve(page):
    path = DOCS / page
    assert path.is_file(), page
    text = path.read_text(encoding="utf-8")
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        if target.startswith(("http://", "https://", "mailto:")):
            continue
        assert (path.parent / target).exists(), f"{page}: broken link {target}"


def _has(obj, name: str) -> bool:
    import dataclasses

    if hasattr(obj, name):
        return True
    return dataclasses.is_dataclass(obj) and name in {f.name for f in dataclasses.fields(obj)}


def _resolve(token: str) -> bool:
    """True when `a.b` names a module attribute or a class attribute (or field) in lidarcat."""
    modules = ["geometry.camera", "survey", "bundle", "geometry.collinearity", "bundle.approx", "lidar",
               "control.facets", "control", "control.batch", "accuracy", "accuracy.standards", "report",
               "pipeline", "stages", "synthetic.survey"]
    head, _, tail = token.partition(".")
    for m in modules:
        mod = importlib.import_module(f"lidarcat.{m}")
        if m.rsplit(".", 1)[-1] == head and hasattr(mod, tail.split(".")[0]):
            return True
        if hasattr(mod, head) and _has(getattr(mod, head), tail.split(".")[0]):
            return True
    return False


def test_method_page_names_real_code():
    text = (DOCS / "method.md").read_text(encoding="utf-8")
    for mod in set(re.findall(r"`lidarcat\.([a-z_]+)`", text)):
        importlib.import_module(f"lidarcat.{mod}")
    tokens = set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*\.[A-Za-z_][A-Za-z0-9_]*)`", text))
    tokens = {t for t in tokens if not t.startswith("lidarcat.") and not t.endswith((".md", ".csv", ".json"))}
    missing = sorted(t for t in tokens if not _resolve(t))
    assert not missing, f"docs/method.md names code that does not exist: {missing}"
    covered: set[int] = set()
    for a, b in re.findall(r"\b(\d{2})-(\d{2})\b", text):
        covered.update(range(int(a), int(b) + 1))
    covered.update(int(n) for n in re.findall(r"^\| (\d{2}) \|", text, flags=re.M))
    covered.update(int(n) for n in re.findall(r"Eq\. (\d{2})", text))
    # eq. 23 (direct georeferencing) is applied by the data provider; the page says so
    missing_eq = sorted(set(range(1, 47)) - covered - {23})
    assert not missing_eq, f"equations not mapped in docs/method.md: {missing_eq}"


def test_notebook_executes():
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    nb = nbformat.read(DOCS / "notebooks" / "thesis_block.ipynb", as_version=4)
    # the notebook uses the library API, never the command line
    source = "\n".join(c.source for c in nb.cells if c.cell_type == "code")
    assert "subprocess" not in source and "!lidarcat" not in source and "CliRunner" not in source
    nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                            resources={"metadata": {"path": str(ROOT)}}).execute()
    text = "\n".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs)
    assert "dof 128, v'Pv 148.3" in text
    assert "sigma0^2 1.16" in text
    assert "mean +0.056 m" in text  # Table 7, dE
    assert any("image/png" in o.get("data", {}) for c in nb.cells if c.cell_type == "code"
               for o in c.outputs)


def _packages() -> list[str]:
    """``lidarcat`` and every package under it (a folder with ``__init__.py``)."""
    import lidarcat

    return ["lidarcat"] + sorted(f"lidarcat.{m.name}" for m in pkgutil.iter_modules(lidarcat.__path__) if m.ispkg)


def _public_modules(package: str) -> list[str]:
    pkg = importlib.import_module(package)
    return sorted(m.name for m in pkgutil.iter_modules(pkg.__path__) if not m.name.startswith("_"))


def _listed(doc: str) -> set[str]:
    """Module names a package docstring lists: ````name```` (a table's first column or the text)
    and ``:mod:`.name```/``:mod:`lidarcat.pkg.name```."""
    names = set(re.findall(r"``([A-Za-z_][A-Za-z0-9_]*)/?``", doc))
    names |= {m.rsplit(".", 1)[-1] for m in re.findall(r":mod:`~?\.?([A-Za-z_][A-Za-z0-9_.]*)`", doc)}
    return names


@pytest.mark.parametrize("package", _packages())
def test_package_docstring_lists_every_module(package):
    """A package face's docstring table names every public module (and package) it holds, and
    every ``:mod:`.name``` it names exists (issue 23: the tables listed 6 and 9 of the real modules)."""
    doc = importlib.import_module(package).__doc__ or ""
    modules = _public_modules(package)
    missing = sorted(set(modules) - _listed(doc))
    assert not missing, f"{package}.__init__ docstring does not list {missing}"
    stale = sorted(m for m in re.findall(r":mod:`\.([A-Za-z_][A-Za-z0-9_]*)`", doc) if m not in modules)
    assert not stale, f"{package}.__init__ docstring names modules that do not exist: {stale}"


def test_layout_page_names_every_package():
    text = (DOCS / "layout.md").read_text(encoding="utf-8")
    for package in _packages()[1:]:
        name = package.split(".", 1)[1]
        assert f"`{name}/`" in text, f"docs/layout.md does not name the package {name}/"
    for name in _public_modules("lidarcat"):
        assert f"`{name}" in text, f"docs/layout.md does not name {name}"


def test_docs_name_existing_test_files():
    """Test files cited by the docs exist (tests moved into tests/<package>/ in issue 23)."""
    pages = [*DOCS.rglob("*.md"), ROOT / "README.md", *(ROOT / "benchmarks").rglob("*.md"),
             *(ROOT / "tests" / "data").rglob("README.md")]
    stale = sorted({f"{p.relative_to(ROOT)}: {m}" for p in pages
                    for m in re.findall(r"tests/[A-Za-z0-9_/]*test_[A-Za-z0-9_]+\.py", p.read_text(encoding="utf-8"))
                    if not (ROOT / m).is_file()})
    assert not stale, f"docs cite test files that do not exist: {stale}"


def test_layout_page_lists_every_module_of_every_package():
    """docs/layout.md's package table names every module (private ones too): the file list is the pipeline."""
    import pkgutil

    text = (DOCS / "layout.md").read_text(encoding="utf-8")
    src = ROOT / "src" / "lidarcat"
    missing = []
    for pkg in sorted(p for p in src.iterdir() if (p / "__init__.py").is_file()):
        row = next((ln for ln in text.splitlines() if ln.startswith(f"| `{pkg.name}/` |")), None)
        assert row is not None, f"docs/layout.md has no row for {pkg.name}/"
        missing += [f"{pkg.name}/{m.name}" for m in pkgutil.iter_modules([str(pkg)]) if f"`{m.name}`" not in row]
    assert not missing, f"docs/layout.md does not name: {missing}"
