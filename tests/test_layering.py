"""The house rules of codegen/ (docs/ARCHITECTURE.md), read from the imports of every module: a package per
pipeline stage, stages in pipeline order, imports only from earlier stages and the shared leaves, no circles."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "codegen"
# The stages in pipeline order: a module may import its own stage and the stages before it, never one after.
STAGES = ("heaters", "job", "toolpath", "gcode", "shapes", "calibrate", "kinematics", "program", "motion", "tables",
          "link", "firmware", "sim", "pipeline", "verify", "report", "cli", "__main__")
# Shared leaves: modules and packages every stage may use, that import no stage themselves.
LEAVES = ("__init__", "errors", "paths", "progress", "stopwatch", "overlap", "targets", "native")


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, Path]:
    return {module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def imports_of(path: Path, known: dict[str, Path]) -> set[str]:
    """The codegen modules a module imports, at its top or inside a function (an import put off is still one)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            # `from codegen.x import y`: y is a module of its own if there is one by that name
            found.update(f"{node.module}.{alias.name}" if f"{node.module}.{alias.name}" in known else node.module
                         for alias in node.names)
    return {name for name in found if name in known}


def stage_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def rank(module: str) -> int:
    stage = stage_of(module)
    if stage in LEAVES:
        return -1
    return STAGES.index(stage)


def graph() -> dict[str, set[str]]:
    known = modules()
    return {name: imports_of(path, known) - {name} for name, path in known.items()}


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected group of more than one module (Tarjan's algorithm, iteratively)."""
    index, low, on_stack, stack, groups = {}, {}, set(), [], []
    for root in edges:
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == node:
                        break
                if len(group) > 1:
                    groups.append(sorted(group))
    return groups


def test_every_module_belongs_to_a_stage_or_is_a_shared_leaf():
    strays = [name for name in modules() if name != "codegen" and stage_of(name) not in STAGES + LEAVES]
    assert strays == []


def test_no_import_circles():
    assert cycles(graph()) == []


def test_imports_run_down_the_pipeline():
    upward = [f"{name} imports {target}" for name, targets in graph().items() for target in sorted(targets)
              if rank(target) > rank(name)]
    assert upward == []


def test_shared_leaves_import_no_stage():
    leaves = [f"{name} imports {target}" for name, targets in graph().items() if rank(name) == -1
              for target in sorted(targets) if rank(target) != -1]
    assert leaves == []


@pytest.mark.parametrize("edges, expected", [
    ({"a": {"b"}, "b": {"a"}, "c": {"a"}}, [["a", "b"]]),
    ({"a": {"b"}, "b": {"c"}, "c": set()}, []),
    ({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"d"}}, [["a", "b", "c"]]),
])
def test_the_circle_finder_finds_circles(edges, expected):
    assert cycles(edges) == expected
