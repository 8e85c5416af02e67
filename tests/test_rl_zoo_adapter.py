"""rl-zoo3 is driven from one module, ``sb3_trpo_plus.application.rl_zoo``: what it replaces in rl-zoo3 for a call is
still there and still read the same way on the installed rl-zoo3, is put back after the call, and no other module
replaces anything of rl-zoo3's."""

from __future__ import annotations

import argparse
import ast
import hashlib
import importlib
import inspect
from pathlib import Path

import pytest
import rl_zoo3
import rl_zoo3.exp_manager
import rl_zoo3.train

from sb3_trpo_plus.application import rl_zoo
from sb3_trpo_plus.application.experiment import TRPOPlusExperimentManager

PACKAGE = Path(__file__).resolve().parents[1] / "sb3_trpo_plus"


def test_what_the_adapter_replaces_is_what_rl_zoo3_reads() -> None:
    for module, name in rl_zoo.REPLACED:
        assert hasattr(importlib.import_module(module), name), f"{module}.{name} is gone"
    assert rl_zoo3.train.ExperimentManager is rl_zoo3.exp_manager.ExperimentManager
    assert rl_zoo3.train.argparse is argparse
    source = inspect.getsource(rl_zoo3.train.train)
    assert "parser = argparse.ArgumentParser()" in source and "args = parser.parse_args()" in source  # sys.argv
    assert "exp_manager = ExperimentManager(" in source
    assert hashlib.sha256(source.encode()).hexdigest() == rl_zoo.TRAIN_SOURCE_SHA256, (
        f"rl-zoo3 {rl_zoo3.__version__}'s train() differs from the {rl_zoo.WRITTEN_AGAINST} source the adapter was "
        "written against: check what sb3_trpo_plus.application.rl_zoo.train replaces, then update the digest"
    )


def test_a_call_puts_back_what_it_replaced(capsys: pytest.CaptureFixture[str]) -> None:
    before = [getattr(importlib.import_module(module), name) for module, name in rl_zoo.REPLACED]
    with pytest.raises(SystemExit) as stop:  # rl-zoo3's parser refuses the flag, in one line
        rl_zoo.train(["--algo", "ppo", "--env", "Pendulum-v1", "--no-such-flag"], TRPOPlusExperimentManager)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines()[-1].startswith("trpo-plus train: error: unrecognized arguments: --no-such-flag")
    after = [getattr(importlib.import_module(module), name) for module, name in rl_zoo.REPLACED]
    assert all(a is b for a, b in zip(before, after, strict=True))


def _replacements(path: Path) -> list[str]:
    """Assignments in ``path`` to an attribute or item of rl-zoo3, of ``sys.argv`` or of ``sys.modules``."""
    tree = ast.parse(path.read_text())
    zoo_names = {
        alias.asname or alias.name
        for node in ast.walk(tree)
        if isinstance(node, ast.Import | ast.ImportFrom)
        for alias in node.names
        if (alias.name if isinstance(node, ast.Import) else f"{node.module}.{alias.name}").startswith("rl_zoo3")
    }
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "setattr" and node.args:
            root = ast.unparse(node.args[0]).split(".")[0]
            if root in zoo_names or root == "sys":
                found.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AugAssign) else []
        for target in targets:
            if isinstance(target, ast.Attribute | ast.Subscript):
                text = ast.unparse(target)
                root = text.split(".")[0].split("[")[0]
                if root in zoo_names or text.startswith(("sys.argv", "sys.modules", "rl_zoo3.")):
                    found.append(f"{path.name}:{node.lineno}: {text}")
    return found


def test_no_other_module_replaces_anything_of_rl_zoo3s() -> None:
    elsewhere = [row for path in sorted(PACKAGE.rglob("*.py")) if path.name != "rl_zoo.py" for row in _replacements(path)]
    assert elsewhere == []
    assert _replacements(PACKAGE / "application" / "rl_zoo.py")  # the scan sees the adapter's own tables


def test_the_one_enjoy_path_needs_no_rl_zoo3_enjoy() -> None:
    from sb3_trpo_plus.application import cli

    assert "rl_zoo3.enjoy" not in inspect.getsource(cli)
