"""The shape of the code base, checked like the import contract: no module over 600 lines, no
function over 80 lines outside the compiled kernels, no use of another module's private names,
and project imports inside functions only where a comment gives the reason.

A module's private name (``_x``) may be used by that module alone (and an object's own private
attributes by its methods, inherited ones included); a seam between modules is a public, named
structure (docs/architecture.md).  The checks read the source (``ast``); they run
nothing of it.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from _paths import repo_root

ROOT = repo_root()
PACKAGES = ("sea_daemon", "benchmarks")
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80

#: private attributes of third-party objects the project must reach, each with its reason
THIRD_PARTY_PRIVATE = {
    # canopen's NMT slave keeps its state in ``_state`` and has no public setter that does not
    # also send a heartbeat/boot-up frame; the device model sets it as a real node's stack would
    "_state",
    # sys._getframe / os._exit: the standard library's documented names
    "_getframe", "_exit",
}


def modules() -> list[Path]:
    return sorted(p for pkg in PACKAGES for p in (ROOT / pkg).rglob("*.py"))


def parsed(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def compiled(fn: ast.AST) -> bool:
    """A numba kernel: decorated with njit (or a call of it)."""
    return any("jit" in ast.unparse(d) for d in getattr(fn, "decorator_list", []))


def defined_private_names(tree: ast.Module) -> set[str]:
    """Every private name the module itself defines: functions, classes, attributes it assigns
    (``x._a = ...``, ``self._a``), class-level names, ``__slots__`` entries and keyword names."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            names.add(node.attr)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.startswith("_"):
            names.add(node.value)              # __slots__, getattr(obj, "_a"), namedtuple fields
        elif isinstance(node, ast.alias):
            names.add(node.asname or node.name.split(".")[0])
    return {n for n in names if n.startswith("_") and not n.startswith("__")}


def private_uses(path: Path) -> list[str]:
    return private_uses_in(parsed(path), str(path.relative_to(ROOT)))


def private_uses_in(tree: ast.Module, where: str) -> list[str]:
    own = defined_private_names(tree)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PACKAGES:
            found += [f"{where}:{node.lineno} imports {node.module}.{a.name}"
                      for a in node.names if a.name.startswith("_") and not a.name.startswith("__")]
        elif (isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__")
              and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))
              and node.attr not in own and node.attr not in THIRD_PARTY_PRIVATE):
            found.append(f"{where}:{node.lineno} reads {ast.unparse(node)}")
    return found


def test_no_module_is_over_600_lines():
    long = [f"{p.relative_to(ROOT)}: {n}" for p in modules()
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES]
    assert not long, long


def test_no_function_is_over_80_lines_outside_the_compiled_kernels():
    long = []
    for p in modules():
        for node in ast.walk(parsed(p)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not compiled(node):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{p.relative_to(ROOT)}:{node.lineno} {node.name}: {n} lines")
    assert not long, long


def test_no_module_uses_another_modules_private_names():
    found = [use for p in modules() for use in private_uses(p)]
    assert not found, found


def test_the_private_name_check_sees_a_use_from_outside():
    """The check above can fail: reading an attribute the module does not define, or importing
    another module's private name, is caught; a module's own private attribute is not."""
    outside = ast.parse("from sea_daemon.core.gp.routing import _route\ndef f(akf):\n    return akf._buf\n")
    assert len(private_uses_in(outside, "probe")) == 2
    own = ast.parse("class A:\n    def __init__(self):\n        self._buf = 1\n"
                    "def g(a):\n    return a._buf\n")
    assert private_uses_in(own, "probe") == []


@pytest.mark.parametrize("pkg", PACKAGES)
def test_project_imports_inside_functions_say_why(pkg):
    """An import of the project inside a function is there for a reason the line above names
    (a heavy optional dependency, a child process's start-up cost): ``# local import: ...``."""
    unexplained = []
    for p in (ROOT / pkg).rglob("*.py"):
        lines = p.read_text().splitlines()
        for fn in ast.walk(parsed(p)):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if isinstance(node, (ast.Import, ast.ImportFrom)):
                    mods = [node.module] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
                    if any(m and m.split(".")[0] in PACKAGES for m in mods):
                        above = lines[node.lineno - 2] if node.lineno >= 2 else ""
                        here = lines[node.lineno - 1]
                        if "local import" not in above and "local import" not in here:
                            unexplained.append(f"{p.relative_to(ROOT)}:{node.lineno}")
    assert not unexplained, unexplained
