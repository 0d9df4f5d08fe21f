"""Stiffness-track SAC for 80,000 steps on tuning seeds; every 16,000-step checkpoint scored on tuning episodes
against the gate's best constant (the scoring of ``../budget_gap/run.py``). Protocol: NOTES.md here, written before
the first run.

    python experiments/sac_budget/run.py --tasks VSWrist/Throw-v0     # one process per task
    python experiments/sac_budget/run.py --table-only
"""

import argparse
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

import vswrist_gym  # noqa: F401
from vswrist_gym.agents.procs import limit_threads
from vswrist_gym.agents.protocol import TUNING_TRAIN_SEEDS
from vswrist_gym.tools.gate import constant_agent

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location("budget_gap_run", HERE.parent / "budget_gap" / "run.py")
scoring = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(scoring)  # gate_selection, returns, train_and_score: the PPO study's, unchanged

TASKS = ("VSWrist/Throw-v0", "VSWrist/Hammer-v1")
SEEDS = TUNING_TRAIN_SEEDS[4:7]
BUDGET, EVERY = 80_000, 16_000  # the trainer schedules a checkpoint every n_timesteps // 5 steps at most
RUNS = HERE.parents[1] / "runs" / "sac_budget"


def result_path(env_id: str) -> Path:
    return HERE / f"results_{env_id.split('/')[1]}.json"  # one file per task: the tasks run in separate processes


def run_task(env_id: str) -> None:
    path = result_path(env_id)
    sel = scoring.gate_selection(env_id)
    c = sel["best_constant"]
    lo, hi = sel["rule_levels"]
    rule_gain = sel["rules"][f"{lo:+.1f},{hi:+.1f}"] - sel["constants"][f"{c:+.1f}"]
    base = scoring.returns(env_id, constant_agent(c), {"config": {}})
    task = json.loads(path.read_text()) if path.exists() else {
        "best_constant": c, "rule_gain": rule_gain, "constant_mean": float(base.mean()), "seeds": {}}
    for seed in SEEDS:
        if str(seed) in task["seeds"]:
            continue
        task["seeds"][str(seed)] = scoring.train_and_score(env_id, "sac", c, seed, base, rule_gain, BUDGET, EVERY, RUNS,
                                                           slack=64)
        path.write_text(json.dumps(task, indent=1) + "\n")


def table() -> None:
    print("| task | " + " | ".join(f"{s:,}" for s in range(EVERY, BUDGET + 1, EVERY)) + " |")
    print("|---|" + "---|" * (BUDGET // EVERY))
    for env_id in TASKS:
        path = result_path(env_id)
        if not path.exists():
            continue
        task = json.loads(path.read_text())
        cells = []
        for step in range(EVERY, BUDGET + 1, EVERY):
            s = [task["seeds"][k][str(step)]["share"] for k in sorted(task["seeds"])]
            cells.append(f"{', '.join(f'{x:+.2f}' for x in s)} (**{np.mean(s):.2f}**)")
        print(f"| {env_id.split('/')[1]} | " + " | ".join(cells) + " |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    ap.add_argument("--table-only", action="store_true")
    args = ap.parse_args()
    if not args.table_only:
        limit_threads(1)
        for env_id in args.tasks:
            run_task(env_id)
    table()
    return 0


if __name__ == "__main__":
    sys.exit(main())
