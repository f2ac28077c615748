"""No import cycles in our packages (docs/architecture.md, "Dependency layering").

Every module of ``solaris_env``, ``training``, ``agents`` and ``benchmarks`` is parsed with ``ast`` (nothing
is imported). An edge A -> B is an import of B that runs when A is imported: any ``import`` / ``from ... import``
outside a function body, including those under module-level ``if``/``try``/``with`` and in class bodies, except
the ones under ``if TYPE_CHECKING:`` (never executed). An import inside a function is an edge A ~> B too: moving
an import into a function defers a cycle, it does not break it (function-local imports are for optional heavy
dependencies, which are not our modules). Relative imports are resolved, and ``from pkg import name`` points at
the submodule ``pkg.name`` when that is a module, else at ``pkg``.
"""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("solaris_env", "training", "agents", "benchmarks")


def _module_files() -> dict[str, Path]:
    """Python files inside regular packages only: a directory without ``__init__.py`` (node_modules of the
    Minecraft backend, which ships Python 2 build scripts) is not importable as ours and is skipped."""
    modules = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            if any(not (d / "__init__.py").is_file() for d in path.parents if d.is_relative_to(ROOT / package)):
                continue
            parts = path.relative_to(ROOT).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join(parts)] = path
    return modules


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.Module):
    """(import statement, whether it sits inside a function) for every import that can run."""
    stack = [(node, False) for node in tree.body]
    while stack:
        node, in_function = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node, in_function
            continue
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            stack.extend((n, in_function) for n in node.orelse)
            continue
        inside = in_function or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        stack.extend((child, inside) for child in ast.iter_child_nodes(node))


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if not node.level:
        return node.module or ""
    package = module.split(".") if is_package else module.split(".")[:-1]
    base = package[: len(package) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def import_graph() -> dict[str, dict[str, bool]]:
    """{module: {imported module: whether every import of it there sits inside a function}}."""
    modules = _module_files()
    graph: dict[str, dict[str, bool]] = {name: {} for name in modules}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        is_package = path.name == "__init__.py"
        for node, in_function in _imports(tree):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                base = _resolve(name, is_package, node)
                targets = []
                for alias in node.names:
                    submodule = f"{base}.{alias.name}"
                    targets.append(submodule if submodule in modules else base)
            for target in targets:
                if target in modules and target != name:
                    graph[name][target] = graph[name].get(target, True) and in_function
    return graph


def find_cycles(graph: dict[str, dict[str, bool]]) -> list[list[str]]:
    """One cycle path per strongly connected component that has one (Tarjan, then a path inside it)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    components: list[set[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for succ in sorted(graph[node]):
            if succ not in index:
                visit(succ)
                low[node] = min(low[node], low[succ])
            elif succ in on_stack:
                low[node] = min(low[node], index[succ])
        if low[node] == index[node]:
            component = set()
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.add(member)
                if member == node:
                    break
            if len(component) > 1:
                components.append(component)

    for node in sorted(graph):
        if node not in index:
            visit(node)

    cycles = []
    for component in components:
        start = min(component)
        # Breadth-first search inside the component for the shortest path start → … → start.
        parents = {start: None}
        frontier = [start]
        found = None
        while frontier and found is None:
            nxt = []
            for node in frontier:
                for succ in sorted(graph[node].keys() & component):
                    if succ == start:
                        found = node
                        break
                    if succ not in parents:
                        parents[succ] = node
                        nxt.append(succ)
                if found is not None:
                    break
            frontier = nxt
        path = [start]
        node = found
        while node is not None and node != start:
            path.insert(1, node)
            node = parents[node]
        cycles.append(path + [start])
    return cycles


def _describe(cycle: list[str], graph: dict[str, dict[str, bool]]) -> str:
    return cycle[0] + "".join(f" {'~>' if graph[a][b] else '->'} {b}" for a, b in zip(cycle, cycle[1:]))


def test_graph_sees_module_level_function_local_and_relative_imports():
    graph = import_graph()
    assert graph["solaris_env"]["solaris_env.lazy"] is False  # module level
    assert graph["solaris_env.cli_env"]["solaris_env.play"] is True  # inside cmd_play
    assert "solaris_env.engine.bots.training_episodes.movement" in graph["solaris_env.engine.bots.training_episodes"]
    relative = ast.parse("from ..x import y").body[0]
    assert _resolve("a.b.c", False, relative) == "a.x" and _resolve("a.b", True, relative) == "a.x"
    assert find_cycles({"a": {"b": True}, "b": {"c": False}, "c": {"a": False}, "d": {}}) == [["a", "b", "c", "a"]]


def test_no_import_cycles():
    graph = import_graph()
    cycles = find_cycles(graph)
    assert not cycles, ("import cycles (-> module level, ~> inside a function):\n"
                        + "\n".join(_describe(c, graph) for c in cycles))
