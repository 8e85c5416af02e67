"""What ``import sb3_trpo_plus`` costs and gives: the public names, the grasp tasks registered, and none of the
application's heavy dependencies (rl-zoo3, Optuna, Ray, matplotlib) imported."""

import json
import subprocess
import sys

HEAVY = ("rl_zoo3", "optuna", "ray", "matplotlib")


def test_import_registers_the_tasks_and_skips_the_application_dependencies() -> None:
    script = (
        "import json, sys, gymnasium\n"
        "from sb3_trpo_plus import TRPOPlus, load_agent, load_eval_agent, make_model, recipe\n"
        f"print(json.dumps({{'heavy': [m for m in {HEAVY!r} if m in sys.modules],"
        " 'registered': 'Grasper3D-v7' in gymnasium.registry}))\n"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    facts = json.loads(result.stdout.splitlines()[-1])
    assert facts == {"heavy": [], "registered": True}
