"""The shape of the code: imports flow one way (algorithms never import harness; no module imports one that imports
it back, counting imports inside functions too), found by walking the AST of every module; no module is longer than a
reader takes in at one sitting."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def import_graph() -> dict[str, set[str]]:
    """module -> the project modules it imports (anywhere in the file); ``from pkg import mod`` counts as mod."""
    mods = {}
    for p in [*(ROOT / "harness").rglob("*.py"), *(ROOT / "algorithms").rglob("*.py")]:
        name = ".".join(p.relative_to(ROOT).with_suffix("").parts)
        mods[name.removesuffix(".__init__")] = p
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for m, p in mods.items():
        package = m if p.name == "__init__.py" else m.rpartition(".")[0]
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.Import):
                graph[m] |= {a.name for a in node.names if a.name in mods}
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join(parts + ([node.module] if node.module else []))
                subs = {f"{base}.{a.name}" for a in node.names} & set(mods)
                graph[m] |= subs or ({base} & set(mods))
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
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

    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles_in_harness_or_algorithms():
    assert cycles(import_graph()) == []


def test_algorithms_never_import_harness():
    bad = {m: sorted(d for d in deps if d.startswith("harness")) for m, deps in import_graph().items()
           if m.startswith("algorithms")}
    assert not {m: d for m, d in bad.items() if d}


def test_the_cycle_finder_finds_cycles():
    assert cycles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


MAX_LINES = 400  # a module a reader takes in at one sitting; a larger one is split by job (runner.py -> request,
# planning, provenance, runner; app.py -> harness/dashboard/)


def test_no_module_over_400_lines():
    files = [*(ROOT / "harness").rglob("*.py"), *(ROOT / "algorithms").rglob("*.py"), ROOT / "app.py"]
    long = {str(p.relative_to(ROOT)): n for p in files if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, f"over {MAX_LINES} lines: {long}"

