"""Stiffness-track PPO for 400,000 steps on tuning seeds; every 80,000-step checkpoint scored on tuning episodes
against the gate's best constant. Protocol: NOTES.md here, written before the first run.

    python experiments/budget_gap/run.py
"""

import json
import shutil
import sys
from pathlib import Path

import numpy as np
import yaml

import vswrist_gym  # noqa: F401
from vswrist_gym.agents.checkpoints import checkpoints, checkpoint_step
from vswrist_gym.agents.evaluate import AgentSpec
from vswrist_gym.agents.procs import limit_threads
from vswrist_gym.agents.protocol import TUNING_EVAL_SEEDS, TUNING_TRAIN_SEEDS, evaluate
from vswrist_gym.agents.train import train
from vswrist_gym.tools.benchmark import track_entry
from vswrist_gym.tools.gate import constant_agent

TASKS = ("VSWrist/Throw-v0", "VSWrist/Hammer-v1")
SEEDS = TUNING_TRAIN_SEEDS[4:7]
BUDGET, EVERY = 400_000, 80_000
EPISODES = 10
HERE = Path(__file__).resolve().parent
RUNS = HERE.parents[1] / "runs" / "budget_gap"


def gate_selection(env_id: str) -> dict:
    return json.loads((HERE.parent / "gate" / f"{env_id.split('/')[1]}.json").read_text())["selection"]


def returns(env_id: str, make_agent, env_kwargs=None) -> np.ndarray:
    # one environment, episode after episode, for every agent: the constant reads that environment's state
    records, _ = evaluate(env_id, make_agent, list(TUNING_EVAL_SEEDS), EPISODES, env_kwargs=env_kwargs, batch=False)
    return np.array([r["return"] for r in records])


def score_checkpoint(run: Path, env_id: str, folder: Path) -> np.ndarray:
    """Returns of one checkpoint: a copy of the run dir whose model.zip is that checkpoint's (the agent loader
    reads a run dir's final model)."""
    view = run.parent / f"{run.name}_at_{checkpoint_step(folder)}"
    if view.exists():
        shutil.rmtree(view)
    view.mkdir()
    for f in ("config.yaml", "run.json"):
        if (run / f).exists():
            shutil.copy2(run / f, view / f)
    for f in folder.iterdir():
        shutil.copy2(f, view / f.name)
    spec = AgentSpec(str(view), checkpoint="final")
    out = returns(env_id, spec.make, spec.env_kwargs)
    shutil.rmtree(view)
    return out


def train_and_score(env_id: str, algo: str, c: float, seed: int, base: np.ndarray, rule_gain: float, budget: int,
                    every: int, runs: Path, slack: int) -> dict:
    """One stiffness-track run of ``algo`` (trained unless its model is there) and its checkpoints every ``every``
    steps scored against the constant's returns ``base``: {step: {"gain", "share"}}. ``slack``: how many steps a
    scheduled checkpoint may come after its target (a rollout's length)."""
    run = runs / env_id.split("/")[1] / f"seed{seed}"
    entry = track_entry(env_id, algo, "stiffness", c, budget=budget)
    entry["vswrist"][env_id].update(checkpoint_freq=every, keep_checkpoints=100)
    run.parent.mkdir(parents=True, exist_ok=True)
    cfg = run.parent / "entry.yaml"
    cfg.write_text(yaml.safe_dump(entry, sort_keys=False))
    if not (run / "model.zip").is_file():
        train(env_id, algo, run, config=cfg, timesteps=budget, seed=seed, progress=False, log=lambda *a: None)
    rows = {}
    saved = {checkpoint_step(f): f for f in checkpoints(run)}
    for target in range(every, budget + 1, every):
        # the scheduled checkpoint: the first at or after the target (the others were saved on the wall-clock timer)
        step = min((s for s in saved if s >= target), default=None)
        if step is None or step - target > slack:
            raise SystemExit(f"{run}: no checkpoint at {target} steps (saved: {sorted(saved)})")
        gain = float((score_checkpoint(run, env_id, saved[step]) - base).mean())
        rows[str(target)] = {"gain": gain, "share": gain / rule_gain}
        print(f"{env_id} seed {seed} step {target} ({step}): gain {gain:+.2f}, share {gain / rule_gain:+.2f}", flush=True)
    return rows


def main() -> int:
    limit_threads(1)
    path = HERE / "results.json"
    doc = json.loads(path.read_text()) if path.exists() else {}
    for env_id in TASKS:
        sel = gate_selection(env_id)
        c = sel["best_constant"]
        lo, hi = sel["rule_levels"]
        rule_gain = sel["rules"][f"{lo:+.1f},{hi:+.1f}"] - sel["constants"][f"{c:+.1f}"]
        base = returns(env_id, constant_agent(c), {"config": {}})
        task = doc.setdefault(env_id, {"best_constant": c, "rule_gain": rule_gain,
                                       "constant_mean": float(base.mean()), "seeds": {}})
        for seed in SEEDS:
            if str(seed) in task["seeds"]:
                continue
            task["seeds"][str(seed)] = train_and_score(env_id, "ppo", c, seed, base, rule_gain, BUDGET, EVERY, RUNS,
                                                       slack=4096)
            path.write_text(json.dumps(doc, indent=1) + "\n")
    print("\n| task | steps | share per seed | mean share |\n|---|---|---|---|")
    for env_id, task in doc.items():
        for step in range(EVERY, BUDGET + 1, EVERY):
            s = [task["seeds"][k][str(step)]["share"] for k in sorted(task["seeds"]) if str(step) in task["seeds"][k]]
            print(f"| {env_id} | {step:,} | {', '.join(f'{x:+.2f}' for x in s)} | {np.mean(s):+.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
