"""A one-change-at-a-time hyperparameter search for Throw-v0's stiffness-track PPO on tuning seeds only.
Protocol: NOTES.md, written before the first run.

    python experiments/throw_tuning/search.py
"""

import copy
import json
import sys
from pathlib import Path

import numpy as np
import yaml

import vswrist_gym  # noqa: F401
from vswrist_gym.agents.evaluate import AgentSpec
from vswrist_gym.agents.procs import limit_threads
from vswrist_gym.agents.protocol import TUNING_EVAL_SEEDS, TUNING_TRAIN_SEEDS, evaluate
from vswrist_gym.agents.train import train
from vswrist_gym.tools.benchmark import track_entry

ENV_ID = "VSWrist/Throw-v0"
BUDGET = 80_000
SEEDS = TUNING_TRAIN_SEEDS[:2]
HERE = Path(__file__).resolve().parent
RUNS = Path("runs/throw_tuning")
NET128 = "dict(log_std_init=-1.5, net_arch=dict(pi=[128, 128], vf=[128, 128]), activation_fn=nn.Tanh)"
CANDIDATES = {
    "base": {}, "lr3e-4": {"learning_rate": 3.0e-4}, "lr1.2e-3": {"learning_rate": 1.2e-3},
    "std-0.5": {"policy_kwargs": "dict(log_std_init=-0.5, net_arch=dict(pi=[64, 64], vf=[64, 64]), "
                                 "activation_fn=nn.Tanh)"},
    "epochs20": {"n_epochs": 20}, "steps64": {"n_steps": 64, "batch_size": 512}, "ent0.005": {"ent_coef": 0.005},
    "net128": {"policy_kwargs": NET128},
}


def config(name: str) -> dict:
    doc = track_entry(ENV_ID, "ppo", "stiffness", 0.0, budget=BUDGET)
    doc = copy.deepcopy(doc)
    doc[ENV_ID].update(CANDIDATES[name])
    return doc


def score(name: str, seed: int) -> float:
    run = RUNS / name / f"seed{seed}"
    if not (run / "model.zip").is_file():
        cfg = RUNS / name / "ppo.yaml"
        cfg.parent.mkdir(parents=True, exist_ok=True)
        cfg.write_text(yaml.safe_dump(config(name), sort_keys=False))
        resume = (run / "config.yaml").is_file()
        train(ENV_ID, "ppo", run, config=None if resume else cfg, timesteps=BUDGET, seed=seed, resume=resume,
              progress=False)
    spec = AgentSpec(str(run), checkpoint="final")
    records, _ = evaluate(ENV_ID, spec.make, TUNING_EVAL_SEEDS, 10, env_kwargs=spec.env_kwargs)
    return float(np.mean([r["return"] for r in records]))


def main() -> int:
    limit_threads(1)
    out = HERE / "results.json"
    doc = json.loads(out.read_text()) if out.is_file() else {}
    for name in CANDIDATES:
        for seed in SEEDS:
            key = f"{name}/{seed}"
            if key not in doc:
                doc[key] = score(name, seed)
                out.write_text(json.dumps(doc, indent=1))
                print(f"{key}: {doc[key]:.2f}", flush=True)
    means = {n: float(np.mean([doc[f"{n}/{s}"] for s in SEEDS])) for n in CANDIDATES}
    best = max(means, key=lambda n: (means[n], n == "base"))
    print("| candidate | change | tuning return, seeds " + ", ".join(map(str, SEEDS)) + " | mean |\n|---|---|---|---|")
    for n, m in means.items():
        print(f"| {'**' + n + '**' if n == best else n} | {CANDIDATES[n] or 'the packaged entry'} | "
              + ", ".join(f"{doc[f'{n}/{s}']:.2f}" for s in SEEDS) + f" | {m:.2f} |")
    print(f"\nwinner: {best}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
