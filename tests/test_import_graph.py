"""The import graph: no cycles among Galileo's modules (imports inside functions count: a lazy
import is still a dependency; those under `if TYPE_CHECKING:` do not: they never run, they name
types for annotations), the library never imports the app, and no module outside a scenario's
folder imports it (the registry names each built-in once, as a string)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _modules(package: Path) -> dict[str, Path]:
    out = {}
    for p in package.rglob("*.py"):
        parts = list(p.relative_to(package.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


def _imports(name: str, path: Path, known: set[str]) -> set[str]:
    """The modules of `known` that module `name` (file `path`) imports, anywhere in it."""
    out = set()
    is_pkg = path.name == "__init__.py"
    tree = ast.parse(path.read_text())
    typing_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If) and _is_type_checking(node.test)
                   for stmt in node.body for n in ast.walk(stmt)}
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found = [target] + [f"{target}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            found = [a.name for a in node.names]
        else:
            continue
        out |= {t for t in found if t in known and t != name and not name.startswith(t + ".")}
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    mods = _modules(ROOT / "galileo")
    return {m: _imports(m, p, set(mods)) for m, p in mods.items()}


def test_the_checker_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_galileo_has_no_import_cycles(graph):
    assert _cycles(graph) == []


def test_the_library_never_imports_the_app():
    for p in (ROOT / "galileo").rglob("*.py"):
        for node in ast.walk(ast.parse(p.read_text())):
            names = ([node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level
                     else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            assert not any(n == "ui" or n.startswith("ui.") or n == "app" for n in names), p


def test_nothing_outside_a_scenarios_folder_imports_it(graph):
    scenarios = {m for m in graph if m.count(".") == 2 and m.startswith("galileo.scenarios.")}
    assert {"galileo.scenarios.ramp", "galileo.scenarios.splash"} <= scenarios
    for m, deps in graph.items():
        for s in scenarios:
            if m == s or m.startswith(s + "."):
                continue
            assert not any(d == s or d.startswith(s + ".") for d in deps), f"{m} imports {s}"
    ui = _modules(ROOT / "ui")
    for m, p in [*ui.items(), ("app", ROOT / "app.py")]:
        text = p.read_text()
        for s in scenarios:
            assert s not in text and s.replace(".", "/") not in text, f"{m} names {s}"
