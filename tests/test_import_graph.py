"""The import graph of sigma's packages: no cycles, and the layering the README promises.

Read statically from the source (every module's imports, deferred ones inside functions included, those under
``if TYPE_CHECKING`` excluded), so the check is fast and independent of import order. Importing ``a.b.c`` runs
``a`` and ``a.b`` first, so an import of ``a.b.c`` counts as an edge to each of them, except to the importing
module's own packages (already being imported when it runs). A cycle in this graph is what makes
``python -c "import sigma_data.experts.door"`` fail with "partially initialized module" in a fresh interpreter,
or makes two modules that only work when imported in the right order.
"""

from __future__ import annotations

import ast
import fnmatch
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sigma_data", "sigma_policy", "pipelines")
# Who may import whom: top-level package -> patterns (fnmatch) of the project modules it may import.
LAYERS = {
    "sigma_data": ("sigma_data", "sigma_data.*"),
    # the data contract and the standard-library file helpers, nothing else of sigma_data (importing them runs
    # sigma_data/__init__.py, which only chooses MuJoCo's GL backend and quiets robosuite's logger)
    "sigma_policy": (
        "sigma_policy",
        "sigma_policy.*",
        "sigma_data",
        "sigma_data.contract",
        "sigma_data.files",
    ),
    "pipelines": ("pipelines", "pipelines.*", "sigma_data", "sigma_data.*", "sigma_policy", "sigma_policy.*"),
}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(path: Path, module: str, known: set[str]) -> set[str]:
    """Project modules ``module`` imports (absolute names; each with the packages above it)."""
    targets: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and _is_type_checking(child):
                for other in child.orelse:
                    visit(other)
                continue
            if isinstance(child, ast.Import):
                targets.update(alias.name for alias in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    pkg = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
                    base = ".".join(pkg[: len(pkg) - child.level + 1] + ([base] if base else []))
                targets.add(base)
                targets.update(f"{base}.{alias.name}" for alias in child.names)
            visit(child)

    visit(ast.parse(path.read_text(), filename=str(path)))
    own = {".".join(module.split(".")[:i]) for i in range(1, module.count(".") + 2)}
    edges = set()
    for target in targets:
        parts = target.split(".")
        for i in range(1, len(parts) + 1):
            name = ".".join(parts[:i])
            if name in known and name not in own:
                edges.add(name)
    return edges


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    known = set(modules)
    return {name: _imports(path, name, known) for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in graph:
        if v not in index:
            strong(v)
    return out


def test_no_import_cycles():
    cycles = _cycles(_graph())
    assert not cycles, "import cycles (each line: modules that import each other):\n" + "\n".join(
        " <-> ".join(c) for c in cycles
    )


def test_layering():
    bad = []
    for module, targets in _graph().items():
        allowed = LAYERS[module.split(".")[0]]
        for target in targets:
            if not any(fnmatch.fnmatchcase(target, pattern) for pattern in allowed):
                bad.append(f"{module} imports {target}")
    assert not bad, "imports across layers:\n" + "\n".join(sorted(bad))


def test_the_checker_sees_a_cycle(tmp_path):
    """The graph reader resolves package imports: a cycle through a package __init__ is found."""
    graph = {"p": {"p.reg"}, "p.reg": {"q.a"}, "q": set(), "q.a": {"p", "p.x"}, "p.x": set()}
    assert _cycles(graph) == [["p", "p.reg", "q.a"]]
    src = tmp_path / "a.py"
    src.write_text(
        "from typing import TYPE_CHECKING\nimport p.x\nif TYPE_CHECKING:\n    import q.a\n"
        "def f():\n    from q import a\n"
    )
    assert _imports(src, "r", {"p", "p.x", "q", "q.a"}) == {"p", "p.x", "q", "q.a"}
    src.write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import q.a\n")
    assert _imports(src, "r", {"p", "p.x", "q", "q.a"}) == set()


@pytest.mark.parametrize(
    "module", ["sigma_data.experts.door", "sigma_data.tasks.stack", "sigma_data.collect"]
)
def test_modules_import_alone_in_a_fresh_interpreter(module):
    """The cases a cycle used to break (the static check above covers every module)."""
    done = subprocess.run(
        [sys.executable, "-c", f"import {module}"], capture_output=True, text=True, cwd=ROOT
    )
    assert done.returncode == 0, done.stderr[-2000:]
