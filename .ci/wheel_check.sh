#!/usr/bin/env bash
# Installable as users install it: `python -m build` makes the sdist and, from the sdist, the wheel; both
# must carry the packages, their data (XML assets, py.typed) and the rl-zoo3 recipes. The wheel is then
# installed (not editable) into a clean virtualenv and, from a folder outside the checkout, runs the
# README's quick start (without extras), then with the zoo extra `trpo-plus enjoy` on a shipped agent
# and `trpo-plus train` on a packaged recipe.
# Usage: .ci/wheel_check.sh   (BUILD_PYTHON: a python with `build`, default .venv/bin/python;
#                              PYTHON: the interpreter of the clean virtualenv, default python3)
set -euo pipefail
cd "$(dirname "$0")/.."
REPO=$PWD
BUILD_PYTHON=${BUILD_PYTHON:-$REPO/.venv/bin/python}
PYTHON=${PYTHON:-python3}
WORK=$(mktemp -d "${TMPDIR:-/tmp}/wheel-check.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
SECONDS=0
step() { echo "== wheel-check [${SECONDS}s]: $*"; }

step "python -m build (sdist, then the wheel built from the sdist)"
if ! "$BUILD_PYTHON" -m build --outdir "$WORK/dist" . >"$WORK/build.log" 2>&1; then
    cat "$WORK/build.log"
    exit 1
fi
WHEEL=$(ls "$WORK"/dist/*.whl)
SDIST=$(ls "$WORK"/dist/*.tar.gz)
ls -l "$WHEEL" "$SDIST"

step "contents of the wheel and the sdist"
"$BUILD_PYTHON" - "$WHEEL" "$SDIST" <<'PY'
import sys
import tarfile
import zipfile
from pathlib import Path

wheel, sdist = sys.argv[1:]
# every module and data file of the packages, and the recipes (packaged under sb3_trpo_plus/)
sources = sorted(
    str(p)
    for package in ("sb3_trpo_plus", "grasp_envs")
    for p in Path(package).rglob("*")
    if p.is_file() and "__pycache__" not in p.parts and p.suffix in {".py", ".xml", ".typed"}
)
recipes = sorted(str(p) for p in Path("zoo_hyperparams").glob("*.yml"))
assert recipes, "zoo_hyperparams/*.yml not found"
assert any(s.startswith("grasp_envs/assets/") for s in sources) and "sb3_trpo_plus/py.typed" in sources

in_wheel = set(zipfile.ZipFile(wheel).namelist())
missing = [s for s in sources if s not in in_wheel] + [r for r in recipes if f"sb3_trpo_plus/{r}" not in in_wheel]
assert not missing, f"missing from the wheel (a new subpackage goes in pyproject.toml's packages): {missing}"
stray = [n for n in in_wheel if n.split("/")[0] in {"trained_agents", "tests", "benchmarks", "docs", "zoo_hyperparams"}]
assert not stray, f"not meant for the wheel: {stray}"

with tarfile.open(sdist) as tar:
    in_sdist = {n.split("/", 1)[1] for n in tar.getnames() if "/" in n}
missing = [s for s in [*sources, *recipes, "pyproject.toml", "README.md"] if s not in in_sdist]
assert not missing, f"missing from the sdist: {missing}"
print(f"wheel: {len(in_wheel)} files, sdist: {len(in_sdist)} entries; {len(sources)} package files and "
      f"{len(recipes)} recipes in both, no trained agents")
PY

step "clean virtualenv: torch==2.13.0 (CPU) first, then the wheel without extras"
"$PYTHON" -m venv "$WORK/venv"
BIN=$WORK/venv/bin
# --no-compile: byte-compiling torch and friends would take longer than the checks themselves
"$BIN/pip" install -q --no-compile "torch==2.13.0"
"$BIN/pip" install -q --no-compile "$WHEEL"

mkdir "$WORK/run"
cd "$WORK/run"  # outside the checkout: only the installed wheel is importable

step "the installed packages and recipes come from the virtualenv"
"$BIN/python" - "$WORK/venv" <<'PY'
import sys
from pathlib import Path

import grasp_envs
import sb3_trpo_plus
from sb3_trpo_plus.application.zoo import ALGO_FILES, ZOO_DIR

venv = Path(sys.argv[1]).resolve()
for where in (Path(sb3_trpo_plus.__file__), Path(grasp_envs.__file__), ZOO_DIR):
    assert venv in where.resolve().parents, f"{where} is not in {venv}"
assert all((ZOO_DIR / name).is_file() for name in ALGO_FILES.values()), ZOO_DIR
assert sb3_trpo_plus.recipe("Reacher2D-v1")["policy"] == "MlpPolicy"  # read without rl-zoo3 installed
print("recipes:", ZOO_DIR)
PY

step "README quick start (a short learn)"
"$BIN/python" - <<'PY'
import gymnasium

import grasp_envs  # noqa: F401
from sb3_trpo_plus import TRPOPlus

env_id = "Grasper3D-v7" if "Grasper3D-v7" in gymnasium.registry else "Grasper3D-v6"
model = TRPOPlus("MlpPolicy", env_id, n_steps=512)
model.learn(2_000, progress_bar=False)
print(f"quick start: {env_id}, {model.num_timesteps} steps")
PY

step "the zoo extra, for the trpo-plus command"
"$BIN/pip" install -q --no-compile "$WHEEL[zoo]"

step "README quick start with the recipe (make_model), shortened rollouts"
# a script file, as in the README: the recipe's worker process re-imports the script that started it
cat > quick_start_recipe.py <<'PY'
import torch

from sb3_trpo_plus import make_model

if __name__ == "__main__":
    torch.set_num_threads(1)
    model = make_model("Grasper3D-v7", seed=0, n_steps=100)  # the recipe's envs, workers and normalisation
    model.learn(2_000, progress_bar=False)
    print(f"make_model: Grasper3D-v7, {model.n_envs} envs, {model.num_timesteps} steps")
    model.env.close()
PY
"$BIN/python" quick_start_recipe.py

step "trpo-plus enjoy on a shipped agent"
"$BIN/trpo-plus" enjoy --env Reacher2D-v1 --folder "$REPO/trained_agents" --no-render -n 100

step "trpo-plus train with the packaged recipe"
"$BIN/trpo-plus" train --env Reacher2D-v1 -n 2000 --seed 0
"$BIN/python" - "$REPO/zoo_hyperparams/trpo_plus.yml" <<'PY'
import sys
from pathlib import Path

import yaml

run = Path("logs/trpo_plus/Reacher2D-v1_1")
assert (run / "Reacher2D-v1.zip").is_file(), sorted(map(str, run.rglob("*")))
used = dict(yaml.load((run / "Reacher2D-v1" / "config.yml").read_text(), Loader=yaml.UnsafeLoader))
recipe = yaml.safe_load(Path(sys.argv[1]).read_text())["Reacher2D-v1"]
scalars = {k: v for k, v in recipe.items() if isinstance(v, (int, float)) and k != "n_timesteps"}
assert scalars and all(used[k] == v for k, v in scalars.items()), (used, scalars)
print(f"train: {run} written with the recipe's {sorted(scalars)}")
PY

step "passed"
