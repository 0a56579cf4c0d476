"""The import graph of the three packages: no cycle, no upward edge.

Layers, lowest first: ``smplik`` (body, IK model, training, data) -> ``shape_inversion`` -> ``workflows``.
A module may import modules of its own layer or of a lower one, never of a higher one, and the graph of
module-to-module imports has no cycle. Every import counts: module level, inside functions, inside
``if TYPE_CHECKING:`` blocks, and relative imports (``from .x import y``).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("smplik", "shape_inversion", "workflows")


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _resolve(name: str, modules: set[str]) -> str | None:
    """The longest prefix of the dotted ``name`` that is a module of the tree (``a.b.func`` -> ``a.b``)."""
    parts = name.split(".")
    while parts:
        candidate = ".".join(parts)
        if candidate in modules:
            return candidate
        parts.pop()
    return None


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Module -> the modules of the three packages it imports (all imports: module and function level)."""
    files = {
        _module_name(path, root): path
        for package in LAYERS
        for path in sorted((root / package).rglob("*.py"))
    }
    modules = set(files)
    graph: dict[str, set[str]] = {module: set() for module in modules}
    for module, path in files.items():
        is_package = path.name == "__init__.py"
        package_parts = module.split(".") if is_package else module.split(".")[:-1]
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base_parts = package_parts[: len(package_parts) - (node.level - 1)]
                    base = ".".join(base_parts + ([node.module] if node.module else []))
                else:
                    base = node.module or ""
                # `from pkg import mod` is an edge to the submodule pkg.mod when there is one, else to pkg.
                targets = [
                    f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base for alias in node.names
                ]
            for target in targets:
                if target.split(".")[0] not in LAYERS:
                    continue
                resolved = _resolve(target, modules)
                if resolved is not None and resolved != module:
                    graph[module].add(resolved)
    return graph


def _layer(module: str) -> int:
    return LAYERS.index(module.split(".")[0])


def upward_edges(graph: dict[str, set[str]]) -> list[str]:
    return sorted(
        f"{module} -> {target}"
        for module, targets in graph.items()
        for target in targets
        if _layer(target) > _layer(module)
    )


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each as a closed path."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []
    counter = 0

    def visit(start: str) -> None:
        nonlocal counter
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    components.append(sorted(component))

    for module in sorted(graph):
        if module not in index:
            visit(module)
    return [_cycle_path(graph, component) for component in components]


def _cycle_path(graph: dict[str, set[str]], component: list[str]) -> list[str]:
    """One closed path through a strongly connected component, for the failure message."""
    members = set(component)
    start = component[0]
    # Breadth-first search back to start inside the component.
    previous: dict[str, str] = {}
    frontier = [start]
    while frontier:
        next_frontier = []
        for node in frontier:
            for child in sorted(graph[node] & members):
                if child == start:
                    path = [start]
                    while node != start:
                        path.append(node)
                        node = previous[node]
                    return [start, *reversed(path[1:]), start] if len(path) > 1 else [start, start]
                if child not in previous:
                    previous[child] = node
                    next_frontier.append(child)
        frontier = next_frontier
    return component


def test_no_upward_import() -> None:
    edges = upward_edges(import_graph())
    layers = " < ".join(LAYERS)
    assert not edges, f"imports from a lower layer to a higher one ({layers}):\n" + "\n".join(edges)


def test_no_import_cycle() -> None:
    cycles = find_cycles(import_graph())
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(cycle) for cycle in cycles)


def _write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_checker_finds_function_level_cycle_and_upward_edge(tmp_path: Path) -> None:
    """The checker itself: a cycle made by an import inside a function, and an upward edge, are both found."""
    _write(
        tmp_path,
        {
            "smplik/__init__.py": "",
            "smplik/a.py": "def f():\n    from workflows.b import g\n    return g\n",
            "shape_inversion/__init__.py": "",
            "workflows/__init__.py": "",
            "workflows/b.py": "from . import c\n",
            "workflows/c.py": "def h():\n    import workflows.b\n",
        },
    )
    graph = import_graph(tmp_path)
    assert upward_edges(graph) == ["smplik.a -> workflows.b"]
    cycles = find_cycles(graph)
    assert len(cycles) == 1
    assert set(cycles[0]) == {"workflows.b", "workflows.c"}
    assert cycles[0][0] == cycles[0][-1]


def test_graph_sees_real_imports() -> None:
    """The graph is not empty by accident: the solver's imports of its own package are edges."""
    graph = import_graph()
    assert "smplik.body_model" in graph["smplik.solver"]
