"""DESIGN's package import table as a test (issue 30).

Every import of every module under poevp_optics/ (module level or inside a function, absolute or
relative; parsed with `ast`, nothing is imported) is mapped to the top-level package it loads, and
checked against `MAY_IMPORT`, the table of docs/architecture.md (a test below keeps the two
equal). What the table does not allow must be in `ALLOWED`, the page's explicit allow-list,
and every allow-list entry must still be needed. The package graph has no cycles.
"""

from __future__ import annotations

import ast
import re

from tests.conftest import ROOT
from tests.helpers import MAY_IMPORT, ROOT_PKG, graph_cycles

PKG = ROOT / "poevp_optics"
DOC = ROOT / "docs" / "architecture.md"
#: (importing module, imported module) -> why it stays for now. Keep minimal; docs/architecture.md
#: prints the same list.
ALLOWED: dict[tuple[str, str], str] = {}


def _module_name(path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = rel.parts[:-1] if rel.parts[-1] == "__init__" else rel.parts
    return ".".join(parts)


def _package_of(module: str) -> str:
    """Top-level package of a dotted module of ours: 'core', ..., 'cli', or the root."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ROOT_PKG


def imports_of(module: str, source: str, is_package: bool = False) -> list[tuple[str, int]]:
    """(imported module of ours, line) for every import in `source`, at any depth. `from a import b`
    yields a.b when b is one of our modules (a subpackage or module file), else a."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".") if is_package else module.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            for a in node.names:
                sub = f"{mod}.{a.name}"
                out.append((sub if _is_ours(sub) else mod, node.lineno))
    return [(m, line) for m, line in out if m == ROOT_PKG or m.startswith(ROOT_PKG + ".")]


def _is_ours(module: str) -> bool:
    rel = PKG.parent.joinpath(*module.split("."))
    return rel.with_suffix(".py").is_file() or (rel / "__init__.py").is_file()


def _all_imports() -> list[tuple[str, str, int]]:
    """(importer, imported, line) over the package, cross-package edges only."""
    edges = []
    for path in sorted(PKG.rglob("*.py")):
        name = _module_name(path)
        for mod, line in imports_of(name, path.read_text(), path.name == "__init__.py"):
            if _package_of(mod) != _package_of(name):
                edges.append((name, mod, line))
    return edges


def _packages_on_disk() -> set[str]:
    pk = {p.name for p in PKG.iterdir() if (p / "__init__.py").is_file()}
    return pk | {p.stem for p in PKG.glob("*.py") if p.stem != "__init__"} | {ROOT_PKG}


def test_the_table_names_every_package():
    assert set(MAY_IMPORT) == _packages_on_disk()


def test_every_import_follows_the_table():
    """0 exceptions beyond the allow-list, and no allow-list entry left that the code no longer needs."""
    bad, used = [], set()
    for name, mod, line in _all_imports():
        if _package_of(mod) in MAY_IMPORT[_package_of(name)]:
            continue
        key = (name, mod)
        if key in ALLOWED:
            used.add(key)
        else:
            bad.append(f"{name}:{line} imports {mod} ({_package_of(name)} may import "
                       f"{sorted(MAY_IMPORT[_package_of(name)]) or 'nothing of ours'})")
    assert not bad, "\n".join(bad)
    assert set(ALLOWED) == used, f"allow-list entries no longer needed: {sorted(set(ALLOWED) - used)}"


def test_no_import_cycle_between_packages():
    """The packages' import graph as the code has it (allow-list included) and as the table allows it."""
    graph: dict[str, set[str]] = {p: set() for p in MAY_IMPORT}
    for name, mod, _ in _all_imports():
        graph[_package_of(name)].add(_package_of(mod))
    assert not graph_cycles(graph), graph_cycles(graph)
    assert not graph_cycles({p: set(v) for p, v in MAY_IMPORT.items()})


def test_the_checker_sees_function_level_and_relative_imports():
    """The parser is what the contract rests on: a core module importing apps/ inside a function,
    relatively, or through `from poevp_optics import apps`, is each found and refused."""
    src = ("def f():\n    from poevp_optics.apps.run import runner\n"
           "def g():\n    from ..apps.run.runner import run_job\n"
           "import poevp_optics.render.renderer\n"
           "from poevp_optics import apps, __version__\n")
    found = imports_of("poevp_optics.core.io", src)
    assert ("poevp_optics.apps.run.runner", 2) in found and ("poevp_optics.apps.run.runner", 4) in found
    assert ("poevp_optics.render.renderer", 5) in found
    assert ("poevp_optics.apps", 6) in found and (ROOT_PKG, 6) in found
    refused = {_package_of(m) for m, _ in found} - MAY_IMPORT["core"] - {"core"}
    assert refused == {"apps", "render", ROOT_PKG}
    assert graph_cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def _doc_table() -> dict[str, frozenset[str]]:
    """docs/architecture.md's package table: row name (`core/`, `cli.py`, `poevp_optics/__init__.py`)
    -> the backticked package names of its 'may import' column."""
    out = {}
    section = DOC.read_text().split("## The package table", 1)[1].split("\n## ", 1)[0]
    for row in re.findall(r"^\|(.+)\|\s*$", section, re.M):
        cells = [c.strip() for c in row.split("|")]
        if len(cells) != 3 or not cells[0].startswith("`"):
            continue
        key = cells[0].strip("`")
        key = ROOT_PKG if key == "poevp_optics/__init__.py" else key.removesuffix("/").removesuffix(".py")
        out[key] = frozenset(re.findall(r"`([a-z_]+)`", cells[2]))
    return out


def test_the_docs_page_prints_this_table_and_allow_list():
    assert _doc_table() == MAY_IMPORT
    text = DOC.read_text()
    for importer, imported in ALLOWED:
        assert f"`{importer}` -> `{imported}`" in text, (importer, imported)
