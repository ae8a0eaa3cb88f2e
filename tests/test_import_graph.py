"""The package's layering, read from the source (every import statement, module level or inside a
function): the daemon and identification never import each other, the formats import none of
the parts that use them, no module of the formats imports one that imports it back, and no
shipped module imports the test oracles.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "admittance"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Every module ``path`` imports, at any depth of its code (relative imports resolved)."""
    here = _module_name(path)
    package = here if path.name == "__init__.py" else here.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            found.add(base)
            found |= {f"{base}.{alias.name}" for alias in node.names}  # `from pkg import module`
    return found


def _graph() -> dict[str, set[str]]:
    modules = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    return {name: {m for m in _imports(path) if m in modules} for name, path in modules.items()}


GRAPH = _graph()


def _in(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def _edges(source: str, target: str) -> list[str]:
    return sorted(f"{a} -> {b}" for a, deps in GRAPH.items() if _in(a, source) for b in deps if _in(b, target))


def test_the_graph_is_read():
    # The rules below mean something only if the parser sees the imports that exist.
    assert "admittance.formats.paramfile" in GRAPH["admittance.daemon.config"]
    assert "admittance.formats.dataset" in GRAPH["admittance.ident.identify"] or \
        "admittance.formats.dataset" in GRAPH["admittance.ident.cli"]


@pytest.mark.parametrize("source, target", [
    ("admittance.daemon", "admittance.ident"),
    ("admittance.ident", "admittance.daemon"),
    ("admittance.ident", "admittance.thesis"),  # the thesis's procedures use the pipeline, not back
])
def test_daemon_and_identification_do_not_import_each_other(source, target):
    assert _edges(source, target) == []


@pytest.mark.parametrize("upper", ["admittance.daemon", "admittance.ident", "admittance.thesis",
                                   "admittance.fidelity", "admittance.mockbench", "admittance.bringup",
                                   "admittance.drivers", "admittance.sim"])
def test_formats_are_the_ground_floor(upper):
    assert _edges("admittance.formats", upper) == []


def test_no_cycle_inside_formats():
    inside = {a: {b for b in deps if _in(b, "admittance.formats") and b != "admittance.formats"}
              for a, deps in GRAPH.items() if _in(a, "admittance.formats")}
    done: set[str] = set()

    def visit(node: str, path: list[str]) -> None:
        if node in path:
            raise AssertionError("import cycle: " + " -> ".join(path[path.index(node):] + [node]))
        if node in done:
            return
        for nxt in sorted(inside.get(node, ())):
            visit(nxt, path + [node])
        done.add(node)

    for module in sorted(inside):
        visit(module, [])


def test_shipped_code_never_imports_the_test_oracles():
    sources = [p for p in PACKAGE.rglob("*.py") if any(m.split(".")[0] in ("oracles", "tests")
                                                       for m in _imports(p))]
    assert sources == []
