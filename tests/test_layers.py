"""The layers import downwards only, and the Snakemake scripts go through the stage layer.

dem <- gns <- calibration <- doe <- pipeline <- workflow/scripts (ARCHITECTURE.md). Every import is
read from the source (module level and inside functions), so a shortcut hidden in a function
counts too.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FLOORS = ["dem", "gns", "calibration", "doe", "pipeline"]
PROJECT = set(FLOORS)


def imports(path: Path) -> set[str]:
    """Every module name imported by a Python file (absolute imports)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def module_of(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def package_files():
    return [p for package in FLOORS for p in sorted((ROOT / package).rglob("*.py"))]


@pytest.mark.parametrize("path", package_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_packages_import_downwards_only_and_know_nothing_of_snakemake(path):
    floor = FLOORS.index(path.relative_to(ROOT).parts[0])
    for name in imports(path):
        top = name.split(".")[0]
        assert top != "snakemake", f"{path.relative_to(ROOT)} imports snakemake"
        if top in PROJECT:
            assert FLOORS.index(top) <= floor, f"{path.relative_to(ROOT)} imports {name}: upwards"


@pytest.mark.parametrize("path", sorted((ROOT / "workflow/scripts").glob("*.py")), ids=lambda p: p.name)
def test_workflow_scripts_call_only_the_stage_layer(path):
    for name in imports(path):
        top = name.split(".")[0]
        assert top == "pipeline" or (top in sys.stdlib_module_names and top not in PROJECT), (
            f"workflow/scripts/{path.name} imports {name}: scripts go through pipeline/"
        )


def test_no_import_cycle_between_files():
    modules = {module_of(p): p for p in package_files()}
    graph = {}
    for module, path in modules.items():
        targets = set()
        for name in imports(path):
            while name and name not in modules:  # "dem.runout.RunoutMethod" -> "dem.runout"
                name = name.rpartition(".")[0]
            if name and name != module and not modules[name].name == "__init__.py":
                targets.add(name)
        graph[module] = targets
    state = {}

    def visit(node, trail):
        state[node] = "open"
        for nxt in graph[node]:
            assert state.get(nxt) != "open", "import cycle: " + " -> ".join(trail + [node, nxt])
            if nxt not in state:
                visit(nxt, trail + [node])
        state[node] = "done"

    for module in graph:
        if module not in state:
            visit(module, [])


def untyped_public_functions(path: Path) -> list[str]:
    """`name (line)` of every public function or method of a public class in `path` that lacks a
    return annotation or an annotation on a parameter (self/cls excepted; __init__ needs none)."""
    found = []

    def check(function, prefix=""):
        args = function.args
        params = args.posonlyargs + args.args + args.kwonlyargs
        if params and params[0].arg in ("self", "cls"):
            params = params[1:]
        params += [a for a in (args.vararg, args.kwarg) if a is not None]
        missing = [a.arg for a in params if a.annotation is None]
        if function.returns is None and function.name != "__init__":
            missing.append("return")
        if missing:
            found.append(f"{prefix}{function.name} (line {function.lineno}: {', '.join(missing)})")

    for node in ast.parse(path.read_text(), str(path)).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not node.name.startswith("_"):
            check(node)
        elif isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
            for item in node.body:
                if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)) and (
                    not item.name.startswith("_") or item.name == "__init__"
                ):
                    check(item, f"{node.name}.")
    return found


@pytest.mark.parametrize("path", package_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_public_functions_have_type_hints(path):
    assert untyped_public_functions(path) == []
