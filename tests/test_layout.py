"""The package's layout: the sub-packages import one way (application -> rollouts -> algorithm -> common), no module
imports another that imports it back, and the flat layout's import paths still work for one release, with a warning."""

from __future__ import annotations

import ast
import importlib
import pickle
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from sb3_trpo_plus import moved

PACKAGE = Path(__file__).resolve().parents[1] / "sb3_trpo_plus"
ROOMS = ("common", "algorithm", "rollouts", "application")  # each may import those before it, never those after
FACADE = {"sb3_trpo_plus", "sb3_trpo_plus.__main__", "sb3_trpo_plus.moved"}  # the public names, above every room


def _module_names() -> dict[str, Path]:
    names = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        names[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return names


MODULES = _module_names()


def imports_of(module: str, source: str | None = None) -> set[str]:
    """The package modules ``module`` imports, at its top or inside functions (not those under ``TYPE_CHECKING``);
    ``source``: its text (default: its file's)."""
    path = MODULES[module]
    tree = ast.parse(path.read_text() if source is None else source)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                continue
            if isinstance(child, ast.Import):
                found.update(alias.name for alias in child.names)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    anchor = package.split(".")[: len(package.split(".")) - child.level + 1]
                    base = ".".join([*anchor, *([base] if base else [])])
                for alias in child.names:
                    found.add(f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base)
            visit(child)

    visit(tree)
    return {name for name in found if name in MODULES and name != module}


def room(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in ROOMS else None


def test_every_module_lives_in_a_room_or_is_the_facade() -> None:
    assert {module for module in MODULES if room(module) is None} == FACADE
    assert {room(module) for module in MODULES} - {None} == set(ROOMS)


def wrong_way(module: str, imported: set[str]) -> list[str]:
    """The imports of ``module`` that go against the rooms' order: a room imports itself and the rooms before it; no
    module imports the facade (``sb3_trpo_plus`` itself), which imports them."""
    own = ROOMS.index(str(room(module)))
    return sorted(name for name in imported if room(name) is None or ROOMS.index(str(room(name))) > own)


@pytest.mark.parametrize("module", sorted(set(MODULES) - FACADE))
def test_imports_run_one_way(module: str) -> None:
    assert wrong_way(module, imports_of(module)) == []


def test_no_import_circle() -> None:
    graph = {module: imports_of(module) for module in MODULES}
    state: dict[str, int] = {}  # 1: on the current path, 2: done

    def walk(module: str, path: list[str]) -> None:
        state[module] = 1
        for name in sorted(graph[module]):
            if state.get(name) == 1:
                raise AssertionError("import circle: " + " -> ".join([*path[path.index(name) :], name]))
            if name not in state:
                walk(name, [*path, name])
        state[module] = 2

    for module in MODULES:
        if module not in state:
            walk(module, [module])


def test_the_checks_see_lazy_relative_and_facade_imports() -> None:
    """The checks above can fail: a function-level import of the application, a relative import of the rollouts and
    an import of the facade, written into an algorithm module, are each refused; a ``TYPE_CHECKING`` import is not."""
    source = (
        "from typing import TYPE_CHECKING\n"
        "from ..rollouts import pool\n"
        "import sb3_trpo_plus\n"
        "if TYPE_CHECKING:\n"
        "    from sb3_trpo_plus.application import agents\n"
        "def f():\n"
        "    from sb3_trpo_plus.application.cli import main\n"
    )
    module = "sb3_trpo_plus.algorithm.update"
    assert wrong_way(module, imports_of(module, source)) == [
        "sb3_trpo_plus",
        "sb3_trpo_plus.application.cli",
        "sb3_trpo_plus.rollouts.pool",
    ]


@pytest.mark.parametrize("old", sorted(moved.MOVED))
def test_an_old_import_path_warns_and_gives_the_new_names(old: str) -> None:
    sys.modules.pop(old, None)
    with pytest.warns(DeprecationWarning, match=rf"{old} moved to {moved.MOVED[old][0]}"):
        module = importlib.import_module(old)
    new = [importlib.import_module(name) for name in moved.MOVED[old]]
    public = [name for name in vars(new[0]) if not name.startswith("_")]
    assert public and all(getattr(module, name) is getattr(new[0], name) for name in public)
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        _ = module.no_such_name


def test_a_pickle_of_the_old_layout_loads() -> None:
    """Models saved by 0.1 name ``sb3_trpo_plus.segment.SegmentRolloutBuffer`` (their rollout buffer class)."""
    from sb3_trpo_plus.algorithm.segment import SegmentRolloutBuffer
    from sb3_trpo_plus.application.run_files import load_normalization

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        assert pickle.loads(b"csb3_trpo_plus.segment\nSegmentRolloutBuffer\n.") is SegmentRolloutBuffer
        assert pickle.loads(b"csb3_trpo_plus.normalization\nload_normalization\n.") is load_normalization


def test_the_warning_points_at_the_importing_line(tmp_path: Path) -> None:
    script = tmp_path / "old_user.py"
    script.write_text("import warnings\nwarnings.simplefilter('always')\nimport sb3_trpo_plus\nimport sb3_trpo_plus.zoo\n")
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, check=True)
    assert f"{script}:4: DeprecationWarning: sb3_trpo_plus.zoo moved to sb3_trpo_plus.application.zoo" in result.stderr
