"""The builtin engine's numba kernels, cached on disk under a digest of the code compiled into them.

Numba's own cache (cache=True) is checked against the source file of the decorated function only.
A kernel of dem.integrate links dem.forces' force kernels, which inline dem.contact's contact law,
and dem.neighbours' pair list, so after an edit of any of them it would go on loading its old
machine code. `kernel` compiles like
nb.njit(cache=True) but adds to each cache entry's key the digest of the kernel's module and of
the kernel modules it imports (transitively): changed code misses the cache and is compiled, in
every process, with no cache files to delete and so nothing for two processes to race on.

The digest is of the code, not the text: sha256 of each module parsed, stripped of docstrings and
written back out by ast.unparse, so an edit of a comment, a docstring or the layout changes
neither the digest nor the engine's version (numba's own check still recompiles the kernels of the
file edited). The same digest names that version (dem.integrate.ENGINE_VERSION), so a trajectory
records which kernel code made it.

The key is set through numba internals (a dispatcher's `_cache`, Cache._index_key; numba 0.68):
tests/test_kernel_cache.py fails should a numba release stop honouring it.

A module whose code or constants a kernel compiles in belongs in KERNEL_MODULES. dem.integrate
and dem.forces import dem.case too, but only for Python-side code (GRAVITY, sphere_mass,
CollapseCase), none of it compiled.
"""

from __future__ import annotations

import ast
import functools
import hashlib
from collections.abc import Callable
from pathlib import Path

import numba as nb
from numba.core.caching import FunctionCache

KERNEL_MODULES = ("dem.contact", "dem.forces", "dem.integrate", "dem.neighbours")
PACKAGE = Path(__file__).parent


def code_of(source: bytes) -> tuple[str, frozenset[str]]:
    """(Python `source`'s code without docstrings or comments, in ast.unparse's layout; the modules
    it imports): what a digest of code, not of text, is taken of."""
    tree = ast.parse(source)
    imports = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            imports.add(node.module)
        elif isinstance(node, ast.Import):
            imports.update(alias.name for alias in node.names)
        elif isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            first = node.body[0]
            if (
                isinstance(first, ast.Expr)
                and isinstance(first.value, ast.Constant)
                and isinstance(first.value.value, str)
            ):
                node.body = node.body[1:] or [ast.Pass()]
    return ast.unparse(tree), frozenset(imports)


@functools.cache
def _parsed(module: str) -> tuple[str, frozenset[str]]:
    """(the kernel module's code_of; the kernel modules it imports)."""
    code, imports = code_of((PACKAGE / f"{module.rpartition('.')[2]}.py").read_bytes())
    return code, imports & frozenset(KERNEL_MODULES)


@functools.cache
def digest(*modules: str) -> str:
    """sha256 (hex) of the code of `modules` and of the kernel modules they import, transitively."""
    todo, seen = list(modules), set()
    while todo:
        module = todo.pop()
        if module not in seen:
            seen.add(module)
            todo.extend(_parsed(module)[1])
    sha = hashlib.sha256()
    for module in sorted(seen):
        sha.update(f"{module}\n{_parsed(module)[0]}\n".encode())
    return sha.hexdigest()


class SourceKeyedCache(FunctionCache):
    """Numba's on-disk cache of one kernel, each entry's key extended by `source_digest`: entries
    of other code stay in the index, unused (going back to that code finds them again)."""

    def __init__(self, py_func: Callable, source_digest: str) -> None:
        self.source_digest = source_digest
        super().__init__(py_func)

    def _index_key(self, sig, codegen):
        return (*super()._index_key(sig, codegen), self.source_digest)


def kernel(**options: object) -> Callable[[Callable], Callable]:
    """nb.njit(cache=True, **options), its cache keyed on the code compiled in (`digest`)."""

    def compiled(func):
        if func.__module__ not in KERNEL_MODULES:
            raise ValueError(f"{func.__module__}.{func.__qualname__}: kernels live in KERNEL_MODULES")
        dispatcher = nb.njit(**options)(func)
        dispatcher._cache = SourceKeyedCache(func, digest(func.__module__))
        return dispatcher

    return compiled
