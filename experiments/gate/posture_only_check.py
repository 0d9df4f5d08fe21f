"""Diagnostic (not part of the gate): a posture-only PPO on a candidate task change, scored on tuning episodes.

The gate's posture-only run (``gate.posture_only_entry``: the id's packaged PPO entry, residual mode, stiffness held
at the constant, 0.15 rad posture residual, 80,000 steps) trained on training seed 0 with ``--config`` settings
over the id, then evaluated (final model) on the 100 tuning episodes (TUNING_EVAL_SEEDS x 10; no held-out episode
is read) paired against the reference agent at that constant, beside the gate's rule at the given levels. Its
share of the rule's gain there says whether the candidate is worth a version and a gate run.

    PYTHONPATH=. python experiments/gate/posture_only_check.py TASK_ID CONSTANT SOFT STIFF [--config JSON]
"""

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import yaml

from vswrist_gym.agents.evaluate import AgentSpec
from vswrist_gym.agents.protocol import TUNING_EVAL_SEEDS
from vswrist_gym.agents.train import train
from vswrist_gym.tools import gate

RUNS = Path("runs/gate_checks")


def main(argv):
    config = {}
    if "--config" in argv:
        k = argv.index("--config")
        config = json.loads(argv[k + 1])
        del argv[k:k + 2]
    env_id, c, soft, stiff = argv[0], float(argv[1]), float(argv[2]), float(argv[3])
    entry = gate.posture_only_entry(env_id, c)
    entry[env_id]["env_kwargs"]["config"] = config
    run_dir = RUNS / env_id.split("/")[-1] / f"seed0_{hashlib.sha1(json.dumps(config, sort_keys=True).encode()).hexdigest()[:8]}"
    if not (run_dir / "model.zip").is_file():
        cfg = run_dir.parent / f"{run_dir.name}.yaml"
        cfg.parent.mkdir(parents=True, exist_ok=True)
        cfg.write_text(yaml.safe_dump(entry, sort_keys=False))
        train(env_id, "ppo", run_dir, config=cfg, timesteps=gate.BUDGET, seed=0, progress=False, log=print)
    spec = AgentSpec(str(run_dir), checkpoint="final")
    kw = {"config": config}
    const = np.array(gate.episode_returns(env_id, gate.constant_agent(c), TUNING_EVAL_SEEDS, 10, kw))
    rule = np.array(gate.episode_returns(env_id, gate.rule_agent((soft, stiff)), TUNING_EVAL_SEEDS, 10, kw))
    ppo = np.array(gate.episode_returns(env_id, spec.make, TUNING_EVAL_SEEDS, 10, spec.env_kwargs))
    r, p = gate.paired(rule, const), gate.paired(ppo, const)
    print(f"{env_id} {json.dumps(config)}: constant s = {c:+.1f} ({const.mean():.1f}); rule ({soft:+.1f}, "
          f"{stiff:+.1f}) {r['mean']:+.1f} (s.e. {r['se']:.1f}); posture-only PPO seed 0 {p['mean']:+.1f} "
          f"(s.e. {p['se']:.1f}); share {p['mean'] / r['mean']:+.2f}; 100 tuning episodes", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
