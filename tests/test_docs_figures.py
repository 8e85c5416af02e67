"""The shipped agents' figures quoted by README.md, docs/environments.md and docs/changelog.md are those of
``trained_agents/agents.json``: each id's success on 100 held-out episodes, and the recommended grasper's seed and
held-out lifts ("195 of 200"). Text only: no env is made."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent
AGENTS: dict[str, dict[str, Any]] = json.loads((ROOT / "trained_agents" / "agents.json").read_text())
RECOMMENDED = "Grasper3D-v7"
DOCS = ("README.md", "docs/environments.md", "docs/changelog.md")

SEED = re.compile(r"\bseed (\d+)\b")  # "seed 0", "--seed 0"; not "seeds 0-19"
COUNT = re.compile(r"(?<![\d,.])(\d[\d,]*) of (\d[\d,]*)(?![\d,])")  # "195 of 200", "1,943 of 2,000"
RATE = re.compile(r"(?<![\d.])\d\.\d\d(?!\d)")  # "0.93"


def _id_pattern(env_id: str) -> re.Pattern[str]:
    return re.compile(rf"(?<![\w-]){re.escape(env_id)}(?![\w-])")


def _blocks(text: str) -> list[str]:
    """Paragraphs, list items and table rows, each as one string."""
    blocks: list[str] = []
    current: list[str] = []
    for line in text.splitlines():
        starts = line.lstrip().startswith(("- ", "* ", "|", "#")) or re.match(r"\s*\d+\. ", line)
        if not line.strip() or starts:
            if current:
                blocks.append(" ".join(current))
            current = []
        if line.strip():
            current.append(line.strip())
            if line.lstrip().startswith(("|", "#")):
                blocks.append(current.pop())
    if current:
        blocks.append(" ".join(current))
    return blocks


def _counts(agent: dict[str, Any]) -> dict[int, int]:
    """Successes per number of evaluation episodes, as agents.json records them."""
    counts = {100: round(agent["success_rate_100"] * 100), agent["episodes"]: round(agent["success_rate"] * agent["episodes"])}
    if "held_out" in agent:
        held_out = agent["held_out"]
        counts[held_out["episodes"]] = round(held_out["success_rate"] * held_out["episodes"])
    return counts


def _figure_problems(block: str, env_id: str, where: str) -> tuple[list[str], set[str]]:
    """Seeds and "N of M" counts in a block about ``env_id``'s shipped agent against agents.json; also which kinds of
    figure the block quotes ("seed", "of <M>")."""
    agent, problems, quoted = AGENTS[env_id], [], set()
    for match in SEED.finditer(block):
        quoted.add("seed")
        if int(match.group(1)) != agent["seed"]:
            problems.append(f"{where}: {env_id}'s shipped agent is seed {agent['seed']}, the text says {match.group(0)!r}")
    expected = _counts(agent)
    for match in COUNT.finditer(block):
        successes, episodes = (int(group.replace(",", "")) for group in match.groups())
        if episodes in expected:
            quoted.add(f"of {episodes}")
            if successes != expected[episodes]:
                problems.append(
                    f"{where}: {env_id}'s shipped agent succeeds {expected[episodes]} of {episodes}, "
                    f"the text says {match.group(0)!r}"
                )
    return problems, quoted


def shipped_agent_problems(text: str, doc: str) -> tuple[list[str], dict[str, set[str]]]:
    """Every paragraph, item or row that speaks of a shipped agent and names exactly one id of agents.json: its seeds
    and counts must be that agent's. Returns the problems and, per id, the kinds of figure quoted."""
    problems: list[str] = []
    quoted: dict[str, set[str]] = {}
    for block in _blocks(text):
        if "shipped" not in block.lower():
            continue
        ids = [env_id for env_id in AGENTS if _id_pattern(env_id).search(block)]
        if len(ids) != 1:
            continue
        found, kinds = _figure_problems(block, ids[0], f"{doc}: {block[:60]!r}")
        problems += found
        quoted.setdefault(ids[0], set()).update(kinds)
    return problems, quoted


def _cells(row: str) -> list[str]:
    return [cell.strip() for cell in row.strip().strip("|").split("|")]


def tasks_table_problems(readme: str) -> list[str]:
    """README's tasks table: each id's shipped-agent column is agents.json's ``success_rate_100`` (a row of several
    versions quotes them as ``v2 0.79``), and the recommended grasper's row quotes its seed and held-out lifts."""
    lines = readme.splitlines()
    header = next((i for i, line in enumerate(lines) if line.startswith("|") and "shipped agent" in line), None)
    if header is None:
        return ["README.md: no tasks table with a 'shipped agent' column"]
    rows = []
    for line in lines[header + 2 :]:
        if not line.startswith("|"):
            break
        rows.append(_cells(line))
    column = next(i for i, cell in enumerate(_cells(lines[header])) if "shipped agent" in cell)
    problems, seen = [], set()
    for cells in rows:
        name, cell = cells[0], cells[column]
        ids = [env_id for env_id in AGENTS if _id_pattern(env_id).search(name)]
        versions = re.findall(r"\bv(\d+) (\d\.\d\d)\b", cell)
        if versions:  # a row of several versions, e.g. `Grasper3D-v1` … `-v6`
            family = name.split("`")[1].rsplit("-v", 1)[0]
            pairs = [(f"{family}-v{version}", rate) for version, rate in versions]
        elif len(ids) == 1:
            rates = RATE.findall(cell)
            pairs = [(ids[0], rates[0] if rates else "no rate")]
        else:
            continue
        for env_id, rate in pairs:
            seen.add(env_id)
            if env_id not in AGENTS:
                problems.append(f"README.md tasks table: {env_id} has no shipped agent in agents.json, the table says {rate}")
            elif rate != f"{AGENTS[env_id]['success_rate_100']:.2f}":
                problems.append(
                    f"README.md tasks table: {env_id}'s shipped agent succeeds {AGENTS[env_id]['success_rate_100']:.2f} "
                    f"on 100 held-out episodes, the table says {rate}"
                )
        if ids == [RECOMMENDED]:
            found, kinds = _figure_problems(cell, RECOMMENDED, "README.md tasks table")
            problems += found
            held_out = AGENTS[RECOMMENDED]["held_out"]["episodes"]
            missing = {"seed", f"of {held_out}"} - kinds
            problems += [f"README.md tasks table: {RECOMMENDED}'s row quotes no '{kind}' figure" for kind in sorted(missing)]
    problems += [f"README.md tasks table: no shipped-agent figure for {env_id}" for env_id in AGENTS if env_id not in seen]
    return problems


# what each document must quote of the recommended grasper's agent, beside agreeing with agents.json wherever it quotes
REQUIRED = {
    "docs/environments.md": {"seed"},
    "docs/changelog.md": {
        "seed",
        f"of {AGENTS[RECOMMENDED]['episodes']}",
        f"of {AGENTS[RECOMMENDED]['held_out']['episodes']}",
    },
}


def _all_problems(texts: dict[str, str]) -> list[str]:
    problems = tasks_table_problems(texts["README.md"])
    for doc, text in texts.items():
        found, quoted = shipped_agent_problems(text, doc)
        problems += found
        missing = REQUIRED.get(doc, set()) - quoted.get(RECOMMENDED, set())
        problems += [f"{doc}: quotes no '{kind}' figure of {RECOMMENDED}'s shipped agent" for kind in sorted(missing)]
    return problems


def _texts() -> dict[str, str]:
    return {doc: (ROOT / doc).read_text() for doc in DOCS}


def test_documents_quote_the_shipped_agents_figures() -> None:
    assert _all_problems(_texts()) == []


@pytest.mark.parametrize(
    ("doc", "old", "new"),
    [
        ("docs/changelog.md", "195 of 200", "191 of 200"),
        ("docs/changelog.md", "recipe's seed 0", "recipe's seed 4"),
        ("docs/changelog.md", "lifts 74 of 100", "lifts 75 of 100"),
        ("docs/environments.md", "command's seed 0", "command's seed 4"),
        ("README.md", "195 of 200", "191 of 200"),
        ("README.md", "recipe's seed 0, 2M", "recipe's seed 4, 2M"),
        ("README.md", "| 0.93 |", "| 0.95 |"),
        ("README.md", "v4 0.74", "v4 0.75"),
        ("README.md", "**0.97**", "**0.98**"),
    ],
)
def test_a_document_quoting_another_figure_fails(doc: str, old: str, new: str) -> None:
    texts = _texts()
    assert old in texts[doc], f"{doc} no longer says {old!r}: update this test's examples"
    texts[doc] = texts[doc].replace(old, new)
    assert _all_problems(texts), f"{doc} with {new!r} instead of {old!r} passed"
