"""The shipped agents (trained_agents/, exported by `python -m benchmarks.convergence agents`) do what the docs say."""

import json
import re
from pathlib import Path

import pytest

from sb3_trpo_plus.application.evaluation import evaluate_agent
from sb3_trpo_plus.application.run_folders import TRAINED_AGENTS, load_trained

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = json.loads((TRAINED_AGENTS / "agents.json").read_text()) if (TRAINED_AGENTS / "agents.json").exists() else {}


def test_every_study_env_has_a_manifest_entry_or_none_yet() -> None:
    assert TRAINED_AGENTS.is_dir(), "trained_agents/ is missing"
    for env_id, entry in MANIFEST.items():
        assert (TRAINED_AGENTS / "trpo_plus" / f"{env_id}_1" / f"{env_id}.zip").is_file(), env_id
        assert entry["episodes"] == 20
        # the env kwargs the docs list are those enjoy makes the env with (config.yml; JSON is YAML)
        config = json.loads((TRAINED_AGENTS / "trpo_plus" / f"{env_id}_1" / env_id / "config.yml").read_text())
        assert entry.get("env_kwargs", {}) == (config.get("env_kwargs") or {}), env_id


@pytest.mark.parametrize("env_id", sorted(MANIFEST))
def test_trained_agent_reaches_its_documented_success_rate(env_id: str) -> None:
    entry = MANIFEST[env_id]
    docs = (ROOT / "docs" / "results.md").read_text()
    row = re.search(rf"^\| `{re.escape(env_id)}` \|.*$", docs, flags=re.MULTILINE)
    assert row is not None, f"docs/results.md has no trained-agent row for {env_id}"
    assert f"{entry['success_rate']:.2f}" in row.group(0)
    model, env, _ = load_trained("trpo_plus", env_id, str(TRAINED_AGENTS), 1, False, entry["eval_seed"], False)
    # the env seeded once with the entry's seed, as it was made, and the later episodes from its own generator
    result = evaluate_agent(model, env, entry["episodes"], seed=entry["eval_seed"], seed_every_episode=False)
    env.close()
    assert result.success_rate >= entry["success_rate"], result


@pytest.mark.parametrize("env_id", sorted(MANIFEST)[:1])
def test_enjoy_finds_the_shipped_agent_without_a_folder(env_id: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from sb3_trpo_plus.application.run_folders import default_folder

    monkeypatch.chdir(tmp_path)  # no ./logs here
    assert default_folder("trpo_plus", env_id) == str(TRAINED_AGENTS)
    (tmp_path / "logs" / "trpo_plus" / f"{env_id}_1").mkdir(parents=True)
    assert default_folder("trpo_plus", env_id) == "logs"


def test_held_out_evaluation_of_a_shipped_agent_is_reproducible(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.syspath_prepend(str(ROOT))  # benchmarks/ is a package of the checkout, not installed
    from benchmarks.held_out import held_out

    run = TRAINED_AGENTS / "trpo_plus" / "Reacher3D-v0_1"
    first = held_out(run, None, 5, 30_000)
    assert first == held_out(run, "Reacher3D-v0", 5, 30_000)  # episode k reset with seed 30,000 + k, whatever ran before
    assert first["episodes"] == 5 and first["eval_seed"] == 30_000
    assert first["successes"] == 5 and first["success_rate"] == 1.0  # the agent reaches on 100 of 100 (docs)
