"""How far the loop-closure welds open inside the environments, with their tools, loads and contacts.

``python -m vswrist_gym.envs.closure [--steps N] [--tasks ...] [--params ...]`` steps every task with two
agents, the analytic baseline commanding the observed posture reference (``reference_to_action(target, 0)``:
smooth references, as a controller sends them) and uniformly random actions (a new posture and stiffness every
control period: reference jumps, as an untrained policy sends them), and prints the worst weld violation (m or
rad, as ``WristSim.loop_closure_error``) after every physics substep. The simulator's own test
(``tests/test_sim.py``) has no tool and no contact; the tasks add heavy tools, walls and holes.
"""

from __future__ import annotations

import argparse

from vswrist_gym import TASKS

AGENTS = ("reference", "random")


def worst_closure(task: str, agent: str, params: str, steps: int, seed: int = 0) -> float:
    """Worst loop-closure error after any physics substep over ``steps`` env steps (episodes reset as they end)."""
    import gymnasium as gym

    env = gym.make(f"VSWrist/{task}-v0", params=params)
    u = env.unwrapped
    sim, worst = u.sim, [0.0]
    step_all = sim.step

    def step_checked(duration_s: float) -> None:  # the same substeps, one at a time, checked after each
        for _ in range(int(round(duration_s / sim.timestep))):
            step_all(sim.timestep)
            worst[0] = max(worst[0], sim.loop_closure_error())

    target = u.obs_slices["target"]
    try:
        obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        sim.step = step_checked
        for _ in range(steps):
            if sim is not u.sim:  # domain randomisation may rebuild the simulator at reset
                raise RuntimeError("the simulator was rebuilt; run with device randomisation off")
            a = env.action_space.sample() if agent == "random" else u.reference_to_action(obs[target], 0.0)
            obs, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                obs, _ = env.reset()
    finally:
        env.close()
    return worst[0]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=300, help="env steps per task and agent (default 300)")
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    ap.add_argument("--params", nargs="+", default=["paper_knm", "paper_knm_fine"],
                    help="device presets to compare (default: the environments' paper_knm and its 0.25 ms step)")
    args = ap.parse_args(argv)
    if args.steps < 1:
        ap.error("--steps must be >= 1")
    cols = [(p, a) for p in args.params for a in AGENTS]
    print(f"worst loop-closure error after any substep, {args.steps} env steps per cell (seed 0)")
    print(f"{'task':<11}" + "".join(f"{p + ' ' + a:>26}" for p, a in cols))
    for task in args.tasks:
        cells = [worst_closure(task, a, p, args.steps) for p, a in cols]
        print(f"{task:<11}" + "".join(f"{c:>26.1e}" for c in cells), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
