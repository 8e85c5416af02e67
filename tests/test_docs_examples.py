"""Every code block of the README and of docs/*.md works as shown.

- Each ``python`` block runs as a script in a fresh interpreter (``python -c``, the working directory a temporary
  folder holding a link to the checkout's ``trained_agents``). A block right after the line
  ``<!-- example: shortened -->`` trains with a long budget: it runs with every ``.learn(N`` cut to ``.learn(1``
  (one update: SB3 collects one full rollout however small the budget).
- Each command of a ``bash`` block is checked without being run: the block runs in bash with the commands replaced
  by stubs that record their arguments (so quoting, ``\\`` continuations, variables and ``VAR=value`` prefixes
  are bash's own), then each recorded command is checked in this process: ``python -m benchmarks.X`` and
  ``trpo-plus VERB`` parse their arguments with the command's own parser (stopped right after the parse),
  ``make TARGET`` is a target the Makefile defines, ``pip install`` names extras pyproject.toml defines, and the
  other tools exist. A TRPOPlus run of ``benchmarks.time_to_grasp`` or ``benchmarks.cg_residuals`` also checks its
  ``--set`` overrides on top of the env's recipe as it stands, as the constructor would (each value in its range,
  the values together), so a documented command that a later recipe refuses fails here. What the commands do is
  tested where they are (tests/test_cli*.py, tests of each benchmark).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import inspect
import os
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import tomllib
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SHORTENED = "<!-- example: shortened -->"
FENCE = re.compile(r"^```(\w*)\s*$")
SHELL_LANGUAGES = {"bash", "sh", "shell", "console"}
# the programs a bash block may call, each replaced by a stub that records its arguments
PROGRAMS = ("python", "python3", "trpo-plus", "make", "pip", "ray", "tensorboard", "apt-get", "mkdocs", "pytest")


def code_blocks(path: Path) -> Iterator[tuple[int, str, str, bool]]:
    """(line number, language, text, shortened) of every fenced block of a Markdown file."""
    lines = path.read_text().splitlines()
    index = 0
    while index < len(lines):
        match = FENCE.match(lines[index])
        if match and match.group(1):
            start = index
            body = []
            index += 1
            while index < len(lines) and not lines[index].startswith("```"):
                body.append(lines[index])
                index += 1
            before = [line for line in lines[:start] if line.strip()]
            shortened = bool(before) and before[-1].strip() == SHORTENED
            yield start + 1, match.group(1), "\n".join(body) + "\n", shortened
        index += 1


def blocks(languages: set[str]) -> list[Any]:
    """The blocks of ``languages`` in every document, each text once (the README and the home page share one)."""
    seen: set[tuple[str, bool]] = set()
    params = []
    for path in DOCUMENTS:
        for line, language, text, shortened in code_blocks(path):
            if language not in languages or (text, shortened) in seen:
                continue
            seen.add((text, shortened))
            # a block that starts Ray shares the xdist worker of the Ray tests (one Ray instance at a time)
            marks = [pytest.mark.xdist_group("ray")] * ("ray" in text)
            params.append(pytest.param(path, text, shortened, id=f"{path.relative_to(ROOT)}:{line}", marks=marks))
    return params


def shorten(text: str) -> str:
    """The script with each ``.learn(<number>`` budget cut to one update."""
    return re.sub(r"\.learn\(\s*(total_timesteps\s*=\s*)?[\d_]+(\.\d+)?(e\d+)?", r".learn(\g<1>1", text)


def test_shorten_cuts_every_learn_budget() -> None:
    text = "model.learn(2_000_000, progress_bar=True)\nTRPOPlus(p, e).learn(total_timesteps=5e6)\nx.learn(n)\n"
    assert shorten(text) == "model.learn(1, progress_bar=True)\nTRPOPlus(p, e).learn(total_timesteps=1)\nx.learn(n)\n"


def test_the_documents_have_examples() -> None:
    """The collection below sees the blocks (a changed fence syntax would make every test below vanish)."""
    assert len(blocks({"python"})) >= 8
    assert len(blocks(SHELL_LANGUAGES)) >= 20


@pytest.mark.slow
@pytest.mark.parametrize(("path", "text", "shortened"), blocks({"python"}))
def test_python_block_runs_as_a_script(path: Path, text: str, shortened: bool, tmp_path: Path) -> None:
    script = shorten(text) if shortened else text
    (tmp_path / "trained_agents").symlink_to(ROOT / "trained_agents")
    environment = {**os.environ, "MUJOCO_GL": "egl", "PYTHONPATH": str(ROOT)}
    result = subprocess.run(
        [sys.executable, "-c", script], cwd=tmp_path, env=environment, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, f"{path.name} block exits {result.returncode}:\n{script}\n{result.stderr[-3000:]}"
    assert "Traceback" not in result.stderr, result.stderr[-3000:]


def recorded_commands(text: str, tmp_path: Path) -> list[list[str]]:
    """The commands a bash block calls, as argument lists, recorded by stubs (nothing is run)."""
    record = tmp_path / "commands"
    stubs = "".join(
        f"""{name}() {{ printf '%s\\0' {shlex.quote(name)} "$@" >> "$RECORD"; printf '\\n' >> "$RECORD"; }}\n"""
        for name in PROGRAMS
    )
    script = f"RECORD={shlex.quote(str(record))}\n{stubs}cd() {{ :; }}\nexport() {{ :; }}\nfunction .() {{ :; }}\n{text}"
    result = subprocess.run(["bash", "-e", "-c", script], capture_output=True, text=True, timeout=30, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    commands = []
    for line in record.read_text().split("\n") if record.exists() else []:
        if line:
            commands.append(line.rstrip("\0").split("\0"))
    return commands


class Parsed(Exception):
    """Raised by the patched ``ArgumentParser.parse_args``: the command line parsed (``namespace``)."""

    def __init__(self, namespace: argparse.Namespace) -> None:
        super().__init__()
        self.namespace = namespace


@pytest.fixture
def parse_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """``ArgumentParser.parse_args`` stops the command right after a successful parse."""
    original = argparse.ArgumentParser.parse_args

    def parse_args(self: argparse.ArgumentParser, *args: Any, **kwargs: Any) -> Any:
        raise Parsed(original(self, *args, **kwargs))

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_args)


def check_parses(main: Any, argv: list[str], monkeypatch: pytest.MonkeyPatch) -> argparse.Namespace:
    """The namespace ``main``'s parser makes of ``argv``; the test fails where it does not parse."""
    monkeypatch.setattr(sys, "argv", ["prog", *argv])
    try:
        main(argv) if inspect.signature(main).parameters else main()
    except Parsed as parsed:
        return parsed.namespace
    except SystemExit as error:
        pytest.fail(f"{argv} does not parse (exit {error.code})")
    pytest.fail(f"{argv}: the command ran past its argument parser")


def trained_recipes(module: str, args: argparse.Namespace) -> tuple[list[str], list[str]]:
    """The envs whose TRPOPlus recipe a parsed benchmark command trains (none for the others), and the ``KEY=VALUE``
    overrides it trains them with: ``args.set``, and the CG warm start that ``cg_residuals`` switches on."""
    if module == "benchmarks.time_to_grasp" and args.command == "run" and args.algo == "trpo_plus":
        return [args.env], args.set
    if module == "benchmarks.cg_residuals" and not args.summary:
        return list(args.envs), [*args.set, "cg_warm_start=true"]
    return [], []


def check_overrides(env_ids: list[str], pairs: list[str], command: list[str]) -> None:
    """``pairs`` (``KEY=VALUE``) on top of each env's TRPOPlus recipe pass the constructor's checks."""
    from benchmarks.time_to_grasp import recipe_overrides
    from sb3_trpo_plus.application.zoo import ALGO_FILES, ZOO_DIR, HyperparameterError, check_constructor_values

    overrides = recipe_overrides(argparse.ArgumentParser(), "--set", pairs)
    recipes = yaml.safe_load((ZOO_DIR / ALGO_FILES["trpo_plus"]).read_text())
    for env_id in env_ids:
        try:
            check_constructor_values({**recipes[env_id], **overrides}, f"{env_id}'s recipe with {pairs}")
        except HyperparameterError as error:
            pytest.fail(f"{shlex.join(command)}: {error}")


def makefile_targets() -> set[str]:
    text = (ROOT / "Makefile").read_text()
    return set(re.findall(r"^([\w-]+):", text, flags=re.MULTILINE))


def check_command(command: list[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    program, *args = command
    if program in {"python", "python3"}:
        if args[:1] == ["-c"]:
            result = subprocess.run([sys.executable, "-c", args[1]], capture_output=True, text=True, cwd=ROOT, timeout=120)
            assert result.returncode == 0, result.stderr
            return
        assert args[:1] == ["-m"], f"python {args}: only -m and -c are shown in the docs"
        module = args[1]
        if module.startswith("benchmarks."):
            monkeypatch.syspath_prepend(str(ROOT))  # benchmarks/ is a package of the checkout, not installed
            parsed = check_parses(importlib.import_module(module).main, args[2:], monkeypatch)
            env_ids, pairs = trained_recipes(module, parsed)
            if env_ids:
                check_overrides(env_ids, pairs, command)
        else:
            assert importlib.util.find_spec(module) is not None, f"python -m {module}: no such module"
    elif program == "trpo-plus":
        from sb3_trpo_plus.application import cli

        for index, arg in enumerate(args[:-1]):
            if arg in {"-conf", "--conf-file"} and not (ROOT / args[index + 1]).exists():  # the user's own recipe file
                shutil.copy(ROOT / "zoo_hyperparams" / "trpo_plus.yml", tmp_path / args[index + 1])
                args[index + 1] = str(tmp_path / args[index + 1])
        check_parses(cli.main, args, monkeypatch)
    elif program == "make":
        targets = [arg for arg in args if "=" not in arg and not arg.startswith("-")]
        assert set(targets) <= makefile_targets(), f"make {args}: unknown target"
    elif program == "pip":
        assert args[:1] == ["install"], f"pip {args}"
        extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
        for arg in args[1:]:
            for group in re.findall(r"\[([\w,\s-]+)\]", arg):
                unknown = {name.strip() for name in group.split(",")} - set(extras)
                assert not unknown, f"pip install {arg}: no extra {unknown} in pyproject.toml"
    elif program in {"ray", "tensorboard", "mkdocs", "pytest"}:
        executable = Path(sys.executable).parent / program
        assert executable.exists() or shutil.which(program), f"{program} is not installed with the extras"
    else:
        assert program == "apt-get", command


@pytest.mark.parametrize(("path", "text", "shortened"), blocks(SHELL_LANGUAGES))
def test_shell_block_commands_parse(
    path: Path, text: str, shortened: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, parse_only: None
) -> None:
    commands = recorded_commands(text, tmp_path)
    assert commands, f"{path.name}: a bash block that calls none of {PROGRAMS}"
    for command in commands:
        check_command(command, monkeypatch, tmp_path)
