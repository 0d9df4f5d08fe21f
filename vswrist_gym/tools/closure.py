"""How far the loop-closure welds open inside the environments, with their tools, loads and contacts.

``python -m vswrist_gym.tools.closure [--steps N] [--seeds ...] [--tasks ...] [--params ...] [--agents ...]``
steps every task with three agents, the analytic baseline commanding the observed posture reference
(``reference_to_action(target, 0)``: smooth references, as a controller sends them), uniformly random actions
(a new posture and stiffness every control period: reference jumps, as an untrained policy sends them) and
bang-bang actions (every component +-1 at random: the largest jumps an action can ask for), and prints, per
task and agent, the worst weld violation (m or rad, as ``WristSim.loop_closure_error``) over all substeps as
the range of the per-seed worsts (lowest..highest: the spread; the highest is the worst over all seeds), and
the share of steps past the environment's ``closure_warn`` (``info["closure_exceeded"]``). The values are the
environments' own ``info["loop_closure"]`` (checked once per physics substep by the native callbacks;
``tests/test_env_inputs.py`` checks it against stepping one substep at a time). The simulator's own test
(``tests/test_sim.py``) has no tool and no contact; the tasks add heavy tools, walls and holes.
"""

from __future__ import annotations

import argparse

import numpy as np

from vswrist_gym import LATEST, TASKS, newest_task_name

AGENTS = ("reference", "random", "bangbang")


def closure_run(task: str, agent: str, params: str, steps: int, seed: int = 0) -> tuple[float, int]:
    """(worst ``info["loop_closure"]``, number of steps with ``info["closure_exceeded"]``) over ``steps`` env
    steps (episodes reset as they end): the worst weld violation at any physics substep of them, and how often
    a step passed the environment's ``closure_warn``."""
    import gymnasium as gym

    if agent not in AGENTS:
        raise ValueError(f"agent must be one of {list(AGENTS)}, got {agent!r}")
    env = gym.make(LATEST[task], params=params)
    u = env.unwrapped
    target = u.obs_slices["target"]
    rng = np.random.default_rng(seed)
    n_act = env.action_space.shape[0]
    worst, exceeded = 0.0, 0
    try:
        obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        for _ in range(steps):
            if agent == "random":
                a = env.action_space.sample()
            elif agent == "bangbang":
                a = rng.choice(np.array([-1.0, 1.0], dtype=np.float32), size=n_act)
            else:
                a = u.reference_to_action(obs[target], 0.0)
            obs, _, terminated, truncated, info = env.step(a)
            worst = max(worst, info["loop_closure"])
            exceeded += bool(info["closure_exceeded"])
            if terminated or truncated:
                obs, _ = env.reset()
    finally:
        env.close()
    return worst, exceeded


def worst_closure(task: str, agent: str, params: str, steps: int, seed: int = 0) -> float:
    """Worst weld violation at any physics substep of ``steps`` env steps (``closure_run``)."""
    return closure_run(task, agent, params, steps, seed)[0]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=300, help="env steps per task, agent and seed (default 300)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="seeds (default 0-4)")
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), type=newest_task_name,
                    help=f"short names or full ids (default all: {' '.join(TASKS)})")
    ap.add_argument("--agents", nargs="+", default=list(AGENTS), choices=AGENTS)
    ap.add_argument("--params", nargs="+", default=["paper_knm", "paper_knm_fine"],
                    help="device presets to compare (default: the environments' paper_knm and its 0.25 ms step)")
    args = ap.parse_args(argv)
    if args.steps < 1:
        ap.error("--steps must be >= 1")
    if any(s < 0 for s in args.seeds):
        ap.error("--seeds must be >= 0")
    cols = [(p, a) for p in args.params for a in args.agents]
    print(f"worst loop-closure error over all substeps, {args.steps} env steps per seed, seeds "
          f"{' '.join(map(str, args.seeds))}; per cell the per-seed worsts, lowest..highest (the highest is the "
          f"worst over all seeds), and the share of all steps flagged closure_exceeded")
    width = 25
    print(f"{'task':<11}" + "".join(f"{p + ' ' + a:>{width}}" for p, a in cols))
    for task in args.tasks:
        cells = []
        for p, a in cols:
            runs = [closure_run(task, a, p, args.steps, seed) for seed in args.seeds]
            per_seed = [w for w, _ in runs]
            share = 100.0 * sum(n for _, n in runs) / (args.steps * len(args.seeds))
            cells.append(f"{min(per_seed):.1e}..{max(per_seed):.1e} {share:3.1f}%")
        print(f"{task:<11}" + "".join(f"{c:>{width}}" for c in cells), flush=True)
    return 0


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
