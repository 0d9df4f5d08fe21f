"""Record reference trajectories of the single environments, to prove that a refactor keeps their behaviour.

``python tests/reference/record.py [out.npz]`` runs every task for two seeds under two policies (random
actions from a fixed generator, and the analytic baseline at stiffness 0) with short episodes (so that resets
happen inside the recording) and one forced divergence (the joint velocities are poisoned before step
``DIVERGE_AT``, so MuJoCo reports bad velocities and the env must terminate with the penalty), and stores the
observations, rewards, terminations, truncations and the numeric ``info`` entries. The default output,
``tests/reference/trajectories.npz``, was recorded from the code before the batched core existed (Polish from
that code plus its period-mean contact force, the one intended change, so VSWrist/Polish-v1; the other tasks'
records were identical); each task runs as its newest version;
``tests/test_batch.py`` replays the same protocol and compares to it.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

TASKS = ("LoadHold", "Polish", "Impact", "Insertion", "Drill")
# the id each task's records were made with: its newest version when recorded (LoadHold-v1 and Drill-v1 came later
# and add a cue to the observation, nothing else)
RECORDED_IDS = {"LoadHold": "VSWrist/LoadHold-v0", "Polish": "VSWrist/Polish-v1", "Impact": "VSWrist/Impact-v0",
                "Insertion": "VSWrist/Insertion-v0", "Drill": "VSWrist/Drill-v0"}
SEEDS = (3, 11)
STEPS = 90                   # control steps per run (episodes of 0.6 s = 30 steps: several resets)
DIVERGE_AT = 47              # the step before which the joint velocities are poisoned
CONFIG = {"episode_s": 0.6, "randomize": {"latency": {"enabled": True}}}
INFO_KEYS = ("posture_error", "contact_force", "peak_contact_force", "rms_contact_force", "elastic_energy", "lam",
             "loop_closure", "closure_exceeded", "time", "is_success")


def run(env, data_of, task: str, seed: int, policy: str, steps: int = STEPS) -> dict:
    """Drive ``env`` (a single gymnasium env) with the protocol; ``data_of(env)`` returns its MjData (to poison)."""
    from vswrist_gym.agents.analytic import AnalyticAgent

    rng = np.random.default_rng(1000 + seed)
    agent = AnalyticAgent(env, stiffness=0.0) if policy == "analytic" else None
    obs, info = env.reset(seed=seed)
    rows = {k: [] for k in ("obs", "reward", "terminated", "truncated") + INFO_KEYS}
    rows["obs"].append(np.asarray(obs, dtype=np.float64))
    for k in ("reward", "terminated", "truncated"):
        rows[k].append(0.0)
    for k in INFO_KEYS:
        rows[k].append(float(info[k]))
    for t in range(steps):
        if agent is None:
            action = rng.uniform(-1.0, 1.0, env.action_space.shape).astype(np.float32)
        else:
            action, _ = agent.predict(obs, deterministic=True)
        if t == DIVERGE_AT:
            data_of(env).qvel[:] = 1e12
        obs, r, term, trunc, info = env.step(action)
        rows["obs"].append(np.asarray(obs, dtype=np.float64))
        rows["reward"].append(float(r))
        rows["terminated"].append(float(term))
        rows["truncated"].append(float(trunc))
        for k in INFO_KEYS:
            rows[k].append(float(info[k]))
        if term or trunc:
            obs, info = env.reset()
            rows["obs"].append(np.asarray(obs, dtype=np.float64))
            for k in ("reward", "terminated", "truncated"):
                rows[k].append(np.nan)
            for k in INFO_KEYS:
                rows[k].append(float(info[k]))
    return {k: np.asarray(v) for k, v in rows.items()}


def versions() -> str:
    """The library versions a recording depends on; a replay with other versions is not compared."""
    import mujoco

    return f"mujoco {mujoco.__version__}, numpy {np.__version__}"


def machine() -> str:
    """Where a recording was made: the versions, then the CPU (stored for the record; the replay's bound covers
    the spread between CPUs, tests/test_batch.py)."""
    import platform

    from vswrist_gym.tools.ship_policies import cpu_id

    return f"{versions()}, {platform.machine()}, {cpu_id()}"


def main(argv=None) -> int:
    import gymnasium as gym

    import vswrist_gym  # noqa: F401  (registers the ids)

    argv = sys.argv[1:] if argv is None else argv
    out = Path(argv[0]) if argv else Path(__file__).with_name("trajectories.npz")
    arrays = {}
    for task in TASKS:
        for seed in SEEDS:
            for policy in ("random", "analytic"):
                env = gym.make(RECORDED_IDS[task], config=CONFIG)
                rec = run(env, lambda e: e.unwrapped.data, task, seed, policy)
                env.close()
                for k, v in rec.items():
                    arrays[f"{task}/{seed}/{policy}/{k}"] = v.astype(np.float32) if k == "obs" else v
                print(task, seed, policy, "diverged" if rec["terminated"][~np.isnan(rec["terminated"])].any()
                      else "NO DIVERGENCE", len(rec["reward"]))
    arrays["machine"] = np.array(machine())
    np.savez_compressed(out, **arrays)
    print(f"wrote {out} ({out.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
