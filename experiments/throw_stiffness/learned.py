"""Does PPO learn Throw's variable stiffness? The stiffness-track PPO (configs/ppo.yaml's Throw-v0 entry as it
is) on benchmark training seeds, scored on the gate's held-out episodes against the gate's selected constant,
with the freeze test: the same episodes with the stiffness command held at the policy's own per-episode mean
(what the *variation* of the stiffness earns). Protocol: NOTES.md, written before the first run.

    python experiments/throw_stiffness/learned.py            # from the repository root, [train] installed
"""

import argparse
import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401
from vswrist_gym.agents.evaluate import AgentSpec
from vswrist_gym.agents.procs import limit_threads
from vswrist_gym.agents.protocol import BENCHMARK_TRAIN_SEEDS, HELDOUT_EVAL_SEEDS, mean_ci, reset_seed, run_episode
from vswrist_gym.agents.train import train
from vswrist_gym.tools.gate import EPISODES_PER_SEED, constant_agent, paired

ENV_ID = "VSWrist/Throw-v0"
BUDGET = 80_000
HERE = Path(__file__).resolve().parent
GATE = HERE.parent / "gate" / "Throw-v0.json"


def heldout_resets() -> list[int]:
    return [reset_seed(s, i) for s in HELDOUT_EVAL_SEEDS for i in range(EPISODES_PER_SEED)]


def policy_and_frozen(run_dir: Path) -> tuple[list[float], list[float], list[float]]:
    """Per held-out episode: the policy's return, its mean stiffness command, and the return of the reference
    agent at that command held constant."""
    spec = AgentSpec(str(run_dir), checkpoint="final")
    env = gym.make(ENV_ID, **spec.env_kwargs)
    agent = spec.make(env)
    ref = gym.make(ENV_ID)
    returns, commands, frozen = [], [], []
    for rs in heldout_resets():
        rec, trace = run_episode(env, agent, rs)
        c = float(np.mean([env.unwrapped.lam_to_stiffness_command(lam) for lam in trace.lam]))
        returns.append(rec["return"])
        commands.append(c)
        frozen.append(run_episode(ref, constant_agent(c)(ref), rs)[0]["return"])
    env.close()
    ref.close()
    return returns, commands, frozen


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=list(BENCHMARK_TRAIN_SEEDS))
    ap.add_argument("--runs-dir", default="runs/throw_stiffness")
    args = ap.parse_args(argv)
    limit_threads(1)
    gate = json.loads(GATE.read_text())
    best = gate["selection"]["best_constant"]
    const = gate["headroom"]["returns"]["constant"][f"{best:+.1f}"]
    headroom = gate["headroom"]["rule_minus_constant"]["mean"]
    out = HERE / "results.json"
    doc = json.loads(out.read_text()) if out.is_file() else {"env_id": ENV_ID, "budget": BUDGET, "runs": {}}
    for seed in args.seeds:
        if str(seed) in doc["runs"]:
            continue
        run_dir = Path(args.runs_dir) / f"seed{seed}"
        if not (run_dir / "model.zip").is_file():
            train(ENV_ID, "ppo", run_dir, timesteps=BUDGET, seed=seed, progress=False)
        returns, commands, frozen = policy_and_frozen(run_dir)
        doc["runs"][str(seed)] = {"returns": returns, "mean_commands": commands, "frozen_returns": frozen,
                                  "vs_constant": paired(returns, const), "vs_frozen": paired(returns, frozen)}
        out.write_text(json.dumps(doc, indent=1))
        r = doc["runs"][str(seed)]
        print(f"seed {seed}: policy - constant {r['vs_constant']['mean']:+.2f}, policy - frozen "
              f"{r['vs_frozen']['mean']:+.2f}", flush=True)
    seeds = sorted(doc["runs"], key=int)
    gain = mean_ci([doc["runs"][s]["vs_constant"]["mean"] for s in seeds])
    freeze = mean_ci([doc["runs"][s]["vs_frozen"]["mean"] for s in seeds])
    share = mean_ci([doc["runs"][s]["vs_constant"]["mean"] / headroom for s in seeds])
    print(f"\n| measure ({len(seeds)} training seeds, 95 % interval over seeds) | value |\n|---|---|\n"
          f"| policy - best constant (s = {best:+.1f}) | {gain['mean']:+.2f} [{gain['low']:+.2f}, {gain['high']:+.2f}] |\n"
          f"| share of the gate's headroom (+{headroom:.2f}) | {share['mean']:.2f} [{share['low']:.2f}, "
          f"{share['high']:.2f}] |\n"
          f"| freeze test: policy - its own mean stiffness held | {freeze['mean']:+.2f} [{freeze['low']:+.2f}, "
          f"{freeze['high']:+.2f}] |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
