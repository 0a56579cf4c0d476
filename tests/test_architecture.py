"""The import graph of the three packages: no cycle, no upward edge.

Layers, lowest first: ``smplik`` (body, IK model, training, data) -> ``shape_inversion`` -> ``workflows``.
A module may import modules of its own layer or of a lower one, never of a higher one, and the graph of
module-to-module imports has no cycle. Every import counts: module level, inside functions, inside
``if TYPE_CHECKING:`` blocks, and relative imports (``from .x import y``).

One upward edge is the design: the console-script entry point (``smplik.cli.main``, the composition root)
reads the command table at the top layer (``workflows.commands``), whose loaders import every command's
module, so every command's dependencies are edges of this graph. It is the only upward edge allowed, and it
takes part in the cycle check.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("smplik", "shape_inversion", "workflows")
COMPOSITION_ROOT = "smplik.cli.main -> workflows.commands"
"""The one upward import: the entry point reads the command table (see the module docstring)."""


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
    edges = [e for e in upward_edges(import_graph()) if e != COMPOSITION_ROOT]
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


def test_the_entry_point_reads_the_command_table_with_one_visible_import() -> None:
    """``smplik.cli.main``'s one upward edge is the table; the table names no command by a string: each row's
    loader returns an attribute of a module that ``workflows.commands`` imports (an edge of the graph)."""
    import importlib
    import inspect

    from workflows.commands import COMMANDS

    graph = import_graph()
    assert [e for e in upward_edges(graph) if e.startswith("smplik.cli.")] == [COMPOSITION_ROOT]
    for name, (loader, short) in COMMANDS.items():
        assert callable(loader) and short, name
        imports = [n for n in ast.walk(ast.parse(inspect.getsource(loader))) if isinstance(n, ast.ImportFrom)]
        assert len(imports) == 1 and len(imports[0].names) == 1, f"{name}: the loader imports one command"
        module, attribute = imports[0].module, imports[0].names[0].name
        assert module in graph["workflows.commands"], f"{name}: {module} is no edge of workflows.commands"
        assert loader() is getattr(importlib.import_module(module), attribute), name


def _module_level_calls_on_imports(root: Path = ROOT) -> list[str]:
    """Module-level call statements whose callee is not the module's own object (``register(x)`` on an imported
    function: a side effect on another module at import time). ``app.command(...)(f)`` on the module's own
    ``app`` is its own business; a ``__main__.py`` is a script."""
    found = []
    for package in LAYERS:
        for path in sorted((root / package).rglob("*.py")):
            if path.name == "__main__.py":
                continue
            tree = ast.parse(path.read_text(encoding="utf-8"))
            own = {t.id for node in tree.body if isinstance(node, (ast.Assign, ast.AnnAssign))
                   for t in (node.targets if isinstance(node, ast.Assign) else [node.target])
                   if isinstance(t, ast.Name)}
            own |= {node.name for node in tree.body if isinstance(node, (ast.FunctionDef, ast.ClassDef))}
            for node in tree.body:
                if isinstance(node, ast.Expr) and isinstance(node.value, ast.Call):
                    base = node.value.func
                    while isinstance(base, (ast.Attribute, ast.Call)):
                        base = base.value if isinstance(base, ast.Attribute) else base.func
                    if not (isinstance(base, ast.Name) and base.id in own):
                        found.append(f"{_module_name(path, root)}:{node.lineno}: {ast.unparse(node)[:80]}")
    return found


def test_no_module_registers_anything_on_import() -> None:
    """No module calls into another at import time (the rig mapper of ``preset="auto"`` is passed explicitly as
    ``rig_mapper``, not installed by importing ``shape_inversion.auto_preset``)."""
    calls = _module_level_calls_on_imports()
    assert not calls, "module-level calls with a side effect on another module:\n" + "\n".join(calls)
    from smplik.data import retarget

    assert not [n for n in vars(retarget) if "register" in n.lower() or n == "_rig_mapper"]


def test_the_side_effect_check_finds_an_import_time_registration(tmp_path: Path) -> None:
    _write(tmp_path, {"smplik/__init__.py": "", "smplik/r.py": "from smplik.q import register\nregister(len)\n",
                      "smplik/ok.py": "import typer\napp = typer.Typer()\napp.command('x')(len)\n",
                      "shape_inversion/__init__.py": "", "workflows/__init__.py": ""})
    assert _module_level_calls_on_imports(tmp_path) == ["smplik.r:2: register(len)"]


def test_preset_auto_needs_the_mapper_passed_even_after_importing_it(tmp_path: Path) -> None:
    import pytest

    import shape_inversion.auto_preset as auto
    from smplik.data.retarget import RetargetError, read_motion, retarget_bvh
    from workflows.examples_gen import write_mixamo_character

    motion = read_motion(write_mixamo_character(tmp_path / "m.bvh"))
    with pytest.raises(RetargetError, match="m.bvh: preset 'auto' needs a rig mapper"):
        retarget_bvh(motion, "auto")
    clip = retarget_bvh(motion, "auto", rig_mapper=auto.auto_preset)
    assert clip.num_frames == motion.num_frames
