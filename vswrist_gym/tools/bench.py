"""``vswrist bench-env``: environment speed on one core, against Gymnasium's ``Ant-v5`` measured in the same run.

For every task (default control rate, default config) it reports:

* env steps per second of CPU time on one core (process pinned to one CPU; CPU time of this process, so that
  other jobs on a shared machine distort the figures less than wall time would), random actions drawn
  beforehand, resets included;
* the physics-alone share: the time spent inside ``WristSim.step`` (springs + motors + ``mj_step`` over the
  control period) during that same run, so the ratio ``env step / physics`` is measured on identical states;
* the same for ``Ant-v5`` (its ``mj_step`` calls timed the same way), as the reference;
* the time per step outside the physics (us), next to the budgets the two relative targets leave for it:
  ``0.25 x physics`` (env/physics <= 1.25) and ``Ant-v5's step - physics`` (as fast as Ant-v5);
* optionally (``--breakdown``) where that time goes, from a second run with more timers: the sensor update
  after the step (``mj_forward``), the analytic controller, the observation, and the rest (action checks,
  task logic, rewards, info, Gymnasium's wrappers);
* optionally (``--vec``) the scaling with stable-baselines3's ``SubprocVecEnv`` on 1 and 2 worker processes.

Each figure is the median of ``--repeats`` runs. Speeds depend on the machine and on what else runs on it;
quote them with the date and the machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from datetime import datetime, timezone

import numpy as np

from vswrist_gym import TASKS


def _pin_one_core() -> int | None:
    try:
        cpu = sorted(os.sched_getaffinity(0))[-1]
        os.sched_setaffinity(0, {cpu})
        return cpu
    except (AttributeError, OSError):
        return None


_clock = time.process_time  # CPU time of this process (the benchmark is single-threaded and pinned)


class _Timer:
    """Wraps a callable and accumulates the CPU time spent in it."""

    def __init__(self, fn):
        self.fn, self.total = fn, 0.0

    def __call__(self, *args, **kwargs):
        t0 = _clock()
        try:
            return self.fn(*args, **kwargs)
        finally:
            self.total += _clock() - t0


def _run(env, actions, physics: _Timer) -> tuple[float, float]:
    """Steps through ``actions`` (resetting at episode ends); returns (env steps/s, physics share of time)."""
    env.reset(seed=0)
    physics.total = 0.0
    t0 = _clock()
    for a in actions:
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()
    wall = _clock() - t0
    return len(actions) / wall, physics.total / wall


def _summary(name: str, runs: list[tuple[float, float]], ctrl_hz: float, substeps: int) -> dict:
    sps = statistics.median(r[0] for r in runs)
    share = statistics.median(r[1] for r in runs)
    return {"task": name, "steps_per_s": sps, "physics_share": share, "overhead_ratio": 1.0 / share,
            "ctrl_hz": ctrl_hz, "substeps": substeps, "physics_steps_per_s": sps * substeps,
            "physics_us": 1e6 * share / sps, "other_us": 1e6 * (1.0 - share) / sps}


# the parts of the time outside the physics that ``--breakdown`` times separately: (label, owner, method)
_PARTS = (("sensor update", "sim", "_forward"), ("sensor update", "sim", "sync_kinematics"),
          ("controller", "ctrl", "step"), ("observation", "env", "_observation"))


def bench_task(name: str, steps: int, repeats: int, breakdown: bool = False) -> dict:
    import gymnasium as gym

    import vswrist_gym  # noqa: F401  (registers the ids)

    env = gym.make(f"VSWrist/{name}-v0")
    u = env.unwrapped
    timer = _Timer(u.sim.step)
    u.sim.step = timer
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps,) + env.action_space.shape).astype(np.float32)
    _run(env, actions[: min(200, steps)], timer)  # warm-up
    runs = [_run(env, actions, timer) for _ in range(repeats)]
    out = _summary(name, runs, 1.0 / u.ctrl_dt, u.n_substeps)
    if breakdown:
        # a separate run, so that the extra timers do not slow the headline figures; parts in us per env step
        owners = {"sim": u.sim, "ctrl": u.ctrl, "env": u}
        parts = []
        for label, owner, method in _PARTS:
            t = _Timer(getattr(owners[owner], method))
            setattr(owners[owner], method, t)
            parts.append((label, t))
        _run(env, actions, timer)  # warm-up with the timers
        for _, t in parts:
            t.total = 0.0
        sps, share = _run(env, actions, timer)
        step_us = 1e6 / sps
        split: dict[str, float] = {"physics": share * step_us}
        for label, t in parts:
            split[label] = split.get(label, 0.0) + 1e6 * t.total / len(actions)
        split["rest"] = step_us - sum(split.values())
        out["breakdown_us"] = split
    env.close()
    return out


def bench_ant(steps: int, repeats: int) -> dict | None:
    import gymnasium as gym
    import mujoco

    try:
        env = gym.make("Ant-v5")
    except Exception as exc:  # noqa: BLE001 - report, do not fail the benchmark
        return {"task": "Ant-v5", "error": str(exc)}
    u = env.unwrapped
    # Gymnasium's MujocoEnv calls mujoco.mj_step(model, data, nstep=frame_skip) from its module namespace
    import gymnasium.envs.mujoco.mujoco_env as me

    timer = _Timer(mujoco.mj_step)
    original = me.mujoco.mj_step
    me.mujoco.mj_step = timer
    try:
        rng = np.random.default_rng(0)
        actions = rng.uniform(env.action_space.low, env.action_space.high,
                              (steps,) + env.action_space.shape).astype(np.float32)
        _run(env, actions[: min(200, steps)], timer)
        runs = [_run(env, actions, timer) for _ in range(repeats)]
    finally:
        me.mujoco.mj_step = original
    env.close()
    return _summary("Ant-v5", runs, 1.0 / u.dt, u.frame_skip)


def _make_env(name: str):
    def thunk():
        import gymnasium as gym

        import vswrist_gym  # noqa: F401

        return gym.make(f"VSWrist/{name}-v0")
    return thunk


def bench_vec(name: str, steps: int) -> dict:
    """Steps per wall-clock second of SB3's SubprocVecEnv with 1 and 2 workers (total over all workers)."""
    from stable_baselines3.common.vec_env import SubprocVecEnv

    out = {"task": name}
    for n in (1, 2):
        venv = SubprocVecEnv([_make_env(name) for _ in range(n)], start_method="fork")
        try:
            venv.seed(0)
            venv.reset()
            rng = np.random.default_rng(0)
            acts = rng.uniform(-1, 1, (steps // n, n, venv.action_space.shape[0])).astype(np.float32)
            for a in acts[:50]:
                venv.step(a)
            t0 = time.perf_counter()
            for a in acts:
                venv.step(a)
            out[f"workers_{n}"] = n * len(acts) / (time.perf_counter() - t0)
        finally:
            venv.close()
    out["scaling_2_over_1"] = out["workers_2"] / out["workers_1"]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="vswrist bench-env", description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    ap.add_argument("--steps", type=int, default=3000, help="env steps per timed run (default 3000)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per environment; the median is reported")
    ap.add_argument("--no-ant", action="store_true", help="skip the Ant-v5 reference")
    ap.add_argument("--vec", action="store_true", help="also measure SubprocVecEnv scaling on 1 and 2 workers")
    ap.add_argument("--breakdown", action="store_true",
                    help="also time the parts of each task's step outside the physics (a separate run)")
    ap.add_argument("--json", metavar="PATH", help="write the results as JSON")
    args = ap.parse_args(argv)
    if args.steps < 10 or args.repeats < 1:
        ap.error("--steps must be >= 10 and --repeats >= 1")

    cpu = _pin_one_core()
    results = {"date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"), "machine": platform.node(),
               "processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
               "pinned_cpu": cpu, "steps": args.steps, "repeats": args.repeats, "envs": []}
    print(f"vswrist bench-env: {args.steps} steps x {args.repeats} runs (median), pinned to CPU {cpu}, "
          f"{results['date']}, {results['cpus']} CPUs")
    ant = None if args.no_ant else bench_ant(args.steps, args.repeats)
    if ant is not None:
        results["ant"] = ant
    header = (f"{'env':<18}{'steps/s':>9}{'x Ant-v5':>9}{'ctrl Hz':>8}{'substeps':>9}{'env/physics':>12}"
              f"{'physics us':>11}{'other us':>9}{'budget 1.25':>12}{'budget Ant':>11}")
    print(header)
    print("-" * len(header))
    ant_ok = ant is not None and "error" not in ant

    def row(label: str, r: dict, rel: str) -> None:
        budget_ratio = 0.25 * r["physics_us"]
        budget_ant = f"{1e6 / ant['steps_per_s'] - r['physics_us']:.0f}" if ant_ok and r is not ant else "-"
        print(f"{label:<18}{r['steps_per_s']:>9.0f}{rel:>9}{r['ctrl_hz']:>8.0f}{r['substeps']:>9d}"
              f"{r['overhead_ratio']:>12.2f}{r['physics_us']:>11.0f}{r['other_us']:>9.0f}{budget_ratio:>12.0f}"
              f"{budget_ant:>11}")

    if ant_ok:
        row("Ant-v5", ant, "1.00")
    elif ant is not None:
        print(f"Ant-v5 unavailable: {ant['error']}")
    for name in args.tasks:
        r = bench_task(name, args.steps, args.repeats, breakdown=args.breakdown)
        if ant_ok:
            r["vs_ant"] = r["steps_per_s"] / ant["steps_per_s"]
        results["envs"].append(r)
        row("VSWrist/" + name, r, f"{r['vs_ant']:.2f}" if "vs_ant" in r else "-")
    print("env/physics: CPU time of env.step over the CPU time spent in the physics step of the same run "
          "(targets: >= Ant-v5, >= 2000 steps/s, <= 1.25).\nother us: time per step outside the physics; "
          "budget 1.25 = 0.25 x physics, budget Ant = Ant-v5's whole step - this task's physics: the most it "
          "may be for each target")
    if args.breakdown:
        labels = list(results["envs"][0]["breakdown_us"])
        print("\nwhere a step's time goes (us per env step, a second run with more timers):")
        print(f"{'env':<18}" + "".join(f"{k:>15}" for k in labels))
        for r in results["envs"]:
            print(f"{'VSWrist/' + r['task']:<18}" + "".join(f"{r['breakdown_us'][k]:>15.1f}" for k in labels))
    if args.vec:
        try:
            os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
        except (AttributeError, OSError):
            pass
        results["vec"] = []
        print(f"\nSubprocVecEnv (all CPUs): {'task':<12}{'1 worker':>10}{'2 workers':>11}{'scaling':>9}")
        for name in args.tasks:
            v = bench_vec(name, args.steps)
            results["vec"].append(v)
            print(f"{'':<26}{name:<12}{v['workers_1']:>10.0f}{v['workers_2']:>11.0f}{v['scaling_2_over_1']:>9.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=2)
        print(f"results written to {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
