"""The package is a layered house (issue 25): no module imports, at the top or inside a
function, a module that (transitively) imports it. ``python tests/test_layout.py`` prints the
graph."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "tendonsense"


def import_graph(package=PACKAGE) -> dict[str, set[str]]:
    """Module → the package's modules it imports anywhere in its source (relative or
    absolute imports, top level or inside functions)."""
    modules = {p.stem for p in package.glob("*.py")} - {"__init__"}
    graph = {}
    for name in sorted(modules):
        tree = ast.parse((package / f"{name}.py").read_text())
        deps = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level == 1 or base.startswith("tendonsense"):
                    base = base.removeprefix("tendonsense").lstrip(".")
                    if base:
                        deps.add(base.split(".")[0])
                    else:  # from . import x, y
                        deps |= {a.name for a in node.names}
            elif isinstance(node, ast.Import):
                deps |= {a.name.split(".")[1] for a in node.names
                         if a.name.startswith("tendonsense.")}
        graph[name] = (deps & modules) - {name}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected group of more than one module (Tarjan)."""
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
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in graph:
        if v not in index:
            visit(v)
    return out


def layers(graph: dict[str, set[str]]) -> list[list[str]]:
    """Modules by layer: each imports only modules of lower layers."""
    level: dict[str, int] = {}

    def depth(v):
        if v not in level:
            level[v] = 0
            level[v] = 1 + max((depth(w) for w in graph[v]), default=-1)
        return level[v]

    for v in graph:
        depth(v)
    return [sorted(v for v in graph if level[v] == k) for k in range(max(level.values()) + 1)]


def test_no_module_imports_one_that_imports_it():
    assert cycles(import_graph()) == []


def test_the_graph_sees_imports_inside_functions(tmp_path):
    """The check can fail: a function-level import that closes a circle is found."""
    (tmp_path / "statics.py").write_text("from .model import Model\n\n\ndef later():\n"
                                         "    from .estimation import problem\n")
    (tmp_path / "estimation.py").write_text("from tendonsense.statics import solve\n")
    (tmp_path / "model.py").write_text("import numpy\n")
    graph = import_graph(tmp_path)
    assert graph == {"statics": {"model", "estimation"}, "estimation": {"statics"},
                     "model": set()}
    assert cycles(graph) == [["estimation", "statics"]]


if __name__ == "__main__":
    g = import_graph()
    found = cycles(g)
    print("circles:", found or "none")
    if not found:
        for k, mods in enumerate(layers(g)):
            print(f"layer {k}: " + ", ".join(f"{m} → {', '.join(sorted(g[m])) or '-'}"
                                            for m in mods))
