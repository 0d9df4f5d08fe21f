"""A one-change-at-a-time hyperparameter search for a task's stiffness-track PPO or SAC on tuning seeds only.
Protocols: NOTES.md here (Throw-v0), ../hammer_tuning/NOTES.md (Hammer-v1), ../throw_tuning2/NOTES.md (Throw-v0's
second round) and ../sac_tuning/NOTES.md (SAC, both headline tasks), each written before its first run.

    python experiments/throw_tuning/search.py
    python experiments/throw_tuning/search.py --task VSWrist/Hammer-v1 --study experiments/hammer_tuning
    python experiments/throw_tuning/search.py --study experiments/throw_tuning2 --seeds 1002 1003
    python experiments/throw_tuning/search.py --algo sac --study experiments/sac_tuning/Throw-v0 --seeds 1004 1005
"""

import argparse
import copy
import json
import re
import sys
import time
from pathlib import Path

import numpy as np
import yaml

import vswrist_gym  # noqa: F401
from vswrist_gym.agents.evaluate import AgentSpec
from vswrist_gym.agents.procs import limit_threads
from vswrist_gym.agents.protocol import TUNING_EVAL_SEEDS, TUNING_TRAIN_SEEDS, evaluate
from vswrist_gym.agents.train import train
from vswrist_gym.tools.benchmark import track_entry

BUDGET = 80_000
SEEDS = TUNING_TRAIN_SEEDS[:2]
HERE = Path(__file__).resolve().parent
POLICY = "dict(log_std_init={std}, net_arch=dict(pi=[{w}, {w}], vf=[{w}, {w}]), activation_fn=nn.Tanh)"


def policy(base: str, std: float | None = None, width: int | None = None) -> str:
    """The entry's ``policy_kwargs`` string with its initial log std and hidden width changed where given."""
    std0 = float(re.search(r"log_std_init=([-0-9.]+)", base).group(1))
    w0 = int(re.search(r"pi=\[(\d+)", base).group(1))
    return POLICY.format(std=std0 if std is None else std, w=w0 if width is None else width)


def candidates(env_id: str, first_throw_round: bool = False) -> dict:
    """One change each from the packaged entry of ``env_id``: Throw-v0's first round as its NOTES.md registered it
    (its entry then had log_std_init -1.5); else the set ../hammer_tuning/NOTES.md registered."""
    common = {"base": {}, "lr3e-4": {"learning_rate": 3.0e-4}, "lr1.2e-3": {"learning_rate": 1.2e-3}}
    if first_throw_round:
        base = "dict(log_std_init=-1.5, net_arch=dict(pi=[64, 64], vf=[64, 64]), activation_fn=nn.Tanh)"
        return {**common, "std-0.5": {"policy_kwargs": policy(base, std=-0.5)},
                "epochs20": {"n_epochs": 20}, "steps64": {"n_steps": 64, "batch_size": 512},
                "ent0.005": {"ent_coef": 0.005}, "net128": {"policy_kwargs": policy(base, width=128)}}
    base = track_entry(env_id, "ppo", "stiffness", 0.0, budget=BUDGET)[env_id]["policy_kwargs"]
    return {**common, "std0.0": {"policy_kwargs": policy(base, std=0.0)},
            "std-1.0": {"policy_kwargs": policy(base, std=-1.0)}, "epochs20": {"n_epochs": 20},
            "steps64": {"n_steps": 64, "batch_size": 512}, "gae0.9": {"gae_lambda": 0.9},
            "clip0.3": {"clip_range": 0.3}, "net128": {"policy_kwargs": policy(base, width=128)}}


def sac_candidates(env_id: str) -> dict:
    """One change each from the packaged SAC entry of ``env_id``: the set ../sac_tuning/NOTES.md registered."""
    base = track_entry(env_id, "sac", "stiffness", 0.0)[env_id]
    steps = int(base["n_timesteps"])
    return {"base": {}, "lr1e-3": {"learning_rate": 1.0e-3}, "ent_auto": {"ent_coef": "auto"},
            "sde": {"use_sde": True, "policy_kwargs": base["policy_kwargs"].replace("dict(", "dict(log_std_init=-3, ")},
            "samples4x": {"n_timesteps": 4 * steps, "train_freq": 4 * int(base["train_freq"])},
            "net128": {"policy_kwargs": base["policy_kwargs"].replace("[64, 64]", "[128, 128]")}}


def config(env_id: str, algo: str, change: dict) -> dict:
    doc = copy.deepcopy(track_entry(env_id, algo, "stiffness", 0.0, budget=BUDGET if algo == "ppo" else None))
    doc[env_id].update(change)
    return doc


def score(env_id: str, algo: str, runs: Path, name: str, change: dict, seed: int) -> tuple[float, float]:
    """The tuning score of one run (trained here unless it is complete) and its wall time in seconds."""
    run = runs / name / f"seed{seed}"
    start = time.perf_counter()
    if not (run / "model.zip").is_file():
        cfg = runs / name / f"{algo}.yaml"
        cfg.parent.mkdir(parents=True, exist_ok=True)
        doc = config(env_id, algo, change)
        cfg.write_text(yaml.safe_dump(doc, sort_keys=False))
        resume = (run / "config.yaml").is_file()
        train(env_id, algo, run, config=None if resume else cfg, timesteps=int(doc[env_id]["n_timesteps"]),
              seed=seed, resume=resume, progress=False)
    spec = AgentSpec(str(run), checkpoint="final")
    records, _ = evaluate(env_id, spec.make, TUNING_EVAL_SEEDS, 10, env_kwargs=spec.env_kwargs)
    return float(np.mean([r["return"] for r in records])), time.perf_counter() - start


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="VSWrist/Throw-v0")
    ap.add_argument("--algo", choices=("ppo", "sac"), default="ppo")
    ap.add_argument("--study", type=Path, default=HERE, help="the study's folder (results.json goes there)")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS), help="training seeds (tuning seeds only)")
    args = ap.parse_args()
    bad = sorted(set(args.seeds) - set(TUNING_TRAIN_SEEDS))
    if bad:
        ap.error(f"--seeds must be tuning training seeds {TUNING_TRAIN_SEEDS[0]}-{TUNING_TRAIN_SEEDS[-1]}, got {bad}")
    seeds = args.seeds
    limit_threads(1)
    if args.algo == "sac":
        CANDIDATES = sac_candidates(args.task)
        study = args.study.resolve()
        runs = Path("runs") / f"{study.parent.name}_{study.name}"
    else:
        CANDIDATES = candidates(args.task, args.task == "VSWrist/Throw-v0" and args.study.resolve() == HERE)
        runs = Path("runs") / args.study.resolve().name
    out = args.study / "results.json"
    doc = json.loads(out.read_text()) if out.is_file() else {}
    for name in CANDIDATES:
        for seed in seeds:
            key = f"{name}/{seed}"
            if key not in doc:
                value, seconds = score(args.task, args.algo, runs, name, CANDIDATES[name], seed)
                doc[key] = value
                if args.algo == "sac":  # the PPO studies' files hold the scores alone
                    doc[f"seconds/{key}"] = round(seconds, 1)
                out.write_text(json.dumps(doc, indent=1))
                print(f"{key}: {doc[key]:.2f} ({seconds:.0f} s)", flush=True)
    means = {n: float(np.mean([doc[f"{n}/{s}"] for s in seeds])) for n in CANDIDATES}
    best = max(means, key=lambda n: (means[n], n == "base"))
    print("| candidate | change | tuning return, seeds " + ", ".join(map(str, seeds)) + " | mean |\n|---|---|---|---|")
    for n, m in means.items():
        print(f"| {'**' + n + '**' if n == best else n} | {CANDIDATES[n] or 'the packaged entry'} | "
              + ", ".join(f"{doc[f'{n}/{s}']:.2f}" for s in seeds) + f" | {m:.2f} |")
    print(f"\nwinner: {best}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
