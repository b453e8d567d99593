"""The import graph of the packages: no cycles between modules, and every dependency pointing down
the layers of docs/architecture.md:

    goflow_common <- assembly <- {perception, learning} <- {planning, sim2real} <- goflow_cli

(perception and learning do not import each other, nor do planning and sim2real; nothing imports
goflow_cli). Imports are read with `ast`, at module level and inside functions alike, so a lazy
import counts as a dependency too. `python tests/test_layers.py` prints the graph's violations."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: package -> layer; an import may point only to a lower layer (or within its own package)
LAYERS = {
    "goflow_common": 0,
    "assembly": 1,
    "perception": 2,
    "learning": 2,
    "planning": 3,
    "sim2real": 3,
    "goflow_cli": 4,
}


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """Every module of the layered packages: dotted name -> file (a package is its __init__.py)."""
    files = {"goflow_cli": root / "goflow_cli.py"}
    for package in LAYERS:
        if not (root / package).is_dir():
            continue
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            files[".".join(parts)] = path
    return files


def imports_of(name: str, path: Path, modules: set[str]) -> set[str]:
    """The modules of `modules` that module `name` (file `path`) imports anywhere in its body: for
    `from a.b import c`, a.b.c if that is a module, else a.b."""
    is_package = path.name == "__init__.py"
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: resolved against this module's package
                package = name.split(".") if is_package else name.split(".")[:-1]
                package = package[: len(package) - node.level + 1]
                base = ".".join([*package, base] if base else package)
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names]
        else:
            continue
        for target in targets:
            while target and target not in modules:  # `import a.b.c` of a non-module c: its package
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """module -> the modules it imports (only the layered packages' modules)."""
    files = module_files(root)
    return {name: imports_of(name, path, set(files)) for name, path in files.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    sys.setrecursionlimit(max(10_000, sys.getrecursionlimit()))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


def layer_violations(graph: dict[str, set[str]]) -> list[str]:
    """Each import that points up the layers or across one: "a.b -> c.d (layer 1 -> 2)"."""
    out = []
    for src, targets in sorted(graph.items()):
        p = src.split(".")[0]
        for dst in sorted(targets):
            q = dst.split(".")[0]
            if p != q and LAYERS[q] >= LAYERS[p]:
                out.append(f"{src} -> {dst} (layer {LAYERS[p]} {p} -> layer {LAYERS[q]} {q})")
    return out


def test_the_graph_is_read():
    graph = import_graph()
    assert "assembly.transition.base" in graph["assembly.transition"]
    assert "goflow_common.errors" in graph["assembly.transition.registry"]
    assert len(graph) > 100


def test_no_import_cycles():
    found = cycles(import_graph())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_dependencies_point_down_the_layers():
    found = layer_violations(import_graph())
    assert not found, "imports against docs/architecture.md's layers:\n" + "\n".join(found)


def test_the_checks_catch_a_cycle_and_an_upward_import():
    graph = {
        "assembly.a": {"assembly.b"},
        "assembly.b": {"assembly.a", "learning.x"},
        "learning.x": {"goflow_common.errors"},
        "perception.y": {"learning.x"},
        "goflow_common.errors": set(),
    }
    assert cycles(graph) == [["assembly.a", "assembly.b"]]
    assert layer_violations(graph) == [
        "assembly.b -> learning.x (layer 1 assembly -> layer 2 learning)",
        "perception.y -> learning.x (layer 2 perception -> layer 2 learning)",
    ]


if __name__ == "__main__":
    graph = import_graph()
    print(f"{len(graph)} modules, {sum(map(len, graph.values()))} imports")
    for component in cycles(graph):
        print("cycle:", " <-> ".join(component))
    for line in layer_violations(graph):
        print("layer:", line)
