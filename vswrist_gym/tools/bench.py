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
import logging
import os
import platform
import statistics
import time
from datetime import datetime, timezone

import numpy as np

from vswrist_gym import LATEST, TASKS, newest_task_name

logger = logging.getLogger(__name__)


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

    env = gym.make(LATEST[name])
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

        return gym.make(LATEST[name])
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


# ----------------------------------------------------------------------------------------------- batched
def _rss_mib() -> float:
    """Resident memory of this process (MiB), from /proc (Linux); NaN elsewhere."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def bench_single(name: str, steps: int, repeats: int) -> dict:
    """us per step of the single env (gym.make) and of a batch of one world, interleaved run by run on the same
    actions (CPU time, pinned): the single env is a view on the batch's step code, so the two should agree."""
    import gymnasium as gym

    import vswrist_gym  # noqa: F401

    env = gym.make(LATEST[name])
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps,) + env.action_space.shape).astype(np.float32)
    batch = gym.make_vec(LATEST[name], num_envs=1, vectorization_mode="vector_entry_point", threads=1)
    res: dict[str, list] = {"single": [], "batch1": []}

    def run_single() -> float:
        env.reset(seed=0)
        t0 = _clock()
        for a in actions:
            _, _, term, trunc, _ = env.step(a)
            if term or trunc:
                env.reset()
        return 1e6 * (_clock() - t0) / len(actions)

    def run_batch() -> float:
        batch.reset(seed=0)
        t0 = _clock()
        for a in actions:
            batch.step(a[None])
        return 1e6 * (_clock() - t0) / len(actions)

    run_single(), run_batch()  # warm-up
    for _ in range(repeats):
        res["single"].append(run_single())
        res["batch1"].append(run_batch())
    env.close()
    batch.close()
    return {k: statistics.median(v) for k, v in res.items()}


def bench_batch(name: str, n: int, steps: int, threads: int, pinned: bool) -> dict:
    """Env steps/s of a batch of ``n`` worlds on ``threads`` physics threads, and (one thread) the ratio of the
    batch's whole step to the time inside the worlds' physics (``WristSim.step``)."""
    import gymnasium as gym

    import vswrist_gym  # noqa: F401

    venv = gym.make_vec(LATEST[name], num_envs=n, vectorization_mode="vector_entry_point", threads=threads)
    core = venv.unwrapped
    # the physics: CPU time inside the worlds' mj_step substeps: timed by the compiled advance itself, plus
    # the time in each world's WristSim.step (the resets' settling, and the steps where the compiled advance
    # does not run)
    compiled = core.batch_sim.lib is not None
    timers = []
    for e in core.envs:
        t = _Timer(e.sim.step)
        e.sim.step = t
        timers.append(t)
    rng = np.random.default_rng(0)
    n_vec = max(steps // n, 10)
    acts = rng.uniform(-1, 1, (n_vec, n) + venv.single_action_space.shape).astype(np.float32)
    venv.reset(seed=0)
    for a in acts[: max(2, n_vec // 10)]:
        venv.step(a)
    for t in timers:
        t.total = 0.0
    if compiled:
        core.physics_seconds = 0.0
    clock = _clock if pinned else time.perf_counter
    t0 = clock()
    for a in acts:
        venv.step(a)
    dt = clock() - t0
    physics = (core.physics_seconds if compiled else 0.0) + sum(t.total for t in timers)
    venv.close()
    out = {"task": name, "n": n, "threads": threads, "steps_per_s": n * n_vec / dt,
           "us_per_world_step": 1e6 * dt / (n * n_vec), "compiled_advance": compiled}
    if threads == 1:
        out["overhead_ratio"] = dt / physics
    return out


def bench_physics_scaling(name: str, n: int, steps: int, threads: int) -> tuple[float | None, float | None]:
    """The hardware's ceiling for the batch's thread speed-up, in the same run: the physics alone of ``n``
    worlds (the compiled advance: substeps, sync and gather, no Python) on ``threads`` threads against one
    thread, wall time; and the floor of env/phys: that one thread's CPU time over the CPU time inside its
    ``mj_step`` substeps (what the advance's own work adds: above all the sync, a full ``mj_forward`` wherever
    the task or the observation reads sensors). (None, None) without the compiled advance."""
    import gymnasium as gym

    import vswrist_gym  # noqa: F401
    venv = gym.make_vec(LATEST[name], num_envs=n, vectorization_mode="vector_entry_point", threads=1)
    core = venv.unwrapped
    bsim = core.batch_sim
    if bsim.lib is None:
        venv.close()
        return None, None
    venv.reset(seed=0)
    worlds = np.arange(n, dtype=np.int32)
    theta = np.ascontiguousarray([e.sim.motor_references() for e in core.envs])
    status = np.zeros(n, dtype=np.int32)
    bounds = np.linspace(0, n, 4 * threads + 1).round().astype(np.int32)
    pool = bsim.pool(threads - 1)
    reps = max(steps // n, 10)
    seconds = np.zeros(n)
    gathered = np.empty((n, bsim.width))

    def run(t: int) -> tuple[float, float]:
        """Wall and CPU seconds of ``reps`` periods on ``t`` threads."""
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(reps):
            if t == 1:
                bsim.advance(worlds, theta, status, seconds, gathered)
            else:
                pool.submit(bsim.handles, worlds, theta, bsim.ctrl_idx, bsim.nstep, bsim.sync, status, None, bounds)
                while pool.run_one() >= 0:
                    pass
                pool.wait()
        return time.perf_counter() - t0, time.process_time() - c0

    one, one_cpu = run(1)
    floor = one_cpu / float(seconds.sum())
    many, _ = run(threads)
    venv.close()
    return one / many, floor


def bench_memory(name: str, n: int) -> dict:
    """Resident memory (MiB) of ``n`` worlds, in a fresh interpreter: after reset and 10 steps, minus the
    interpreter with everything imported."""
    import subprocess
    import sys

    code = f"""
import gymnasium as gym, numpy as np, vswrist_gym, stable_baselines3
from vswrist_gym.tools.bench import _rss_mib
import vswrist_gym.envs.batch
base = _rss_mib()
v = gym.make_vec("{LATEST[name]}", num_envs={n}, vectorization_mode="vector_entry_point")
v.reset(seed=0)
for _ in range(10):
    v.step(v.action_space.sample())
print(_rss_mib() - base, _rss_mib())
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1800)
    if res.returncode != 0:
        return {"task": name, "n": n, "error": res.stderr.strip().splitlines()[-1:]}
    worlds, total = map(float, res.stdout.split()[-2:])
    return {"task": name, "n": n, "worlds_mib": worlds, "process_mib": total}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="vswrist bench-env", description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), type=newest_task_name,
                    help=f"short names or full ids (default all: {' '.join(TASKS)})")
    ap.add_argument("--steps", type=int, default=3000, help="env steps per timed run (default 3000)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per environment; the median is reported")
    ap.add_argument("--no-ant", action="store_true", help="skip the Ant-v5 reference")
    ap.add_argument("--vec", action="store_true", help="also measure SubprocVecEnv scaling on 1 and 2 workers")
    ap.add_argument("--breakdown", action="store_true",
                    help="also time the parts of each task's step outside the physics (a separate run)")
    ap.add_argument("--batch", type=int, nargs="?", const=32, default=0, metavar="N",
                    help="also the batched core (gym.make_vec): N worlds (default 32) on 1 and --threads threads, "
                         "and the single env against its pre-batch step; ends with the targets table")
    ap.add_argument("--threads", type=int, default=2, help="physics threads of the threaded batch run (default 2)")
    ap.add_argument("--memory", type=int, default=0, metavar="N",
                    help="also the resident memory of N worlds of the heaviest task (Insertion), e.g. 256, in a "
                         "fresh interpreter (with or without --batch)")
    ap.add_argument("--json", metavar="PATH", help="write the results as JSON")
    args = ap.parse_args(argv)
    if args.steps < 10 or args.repeats < 1:
        ap.error("--steps must be >= 10 and --repeats >= 1")
    if args.batch < 0 or args.threads < 1 or args.memory < 0:
        ap.error("--batch and --memory must be >= 0 worlds, --threads >= 1")

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
    if args.batch or args.memory:
        _batched(args, results, cpu)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=2)
        logger.info(f"wrote {args.json}")
    return 0


def _batched(args, results: dict, cpu) -> None:
    """The batched core's figures and the table of its speed targets."""
    n, rows = args.batch, []
    results["batch"] = {"n": n, "tasks": [], "single": []}
    tasks = args.tasks if n else []
    if n:
        print(f"\nbatched core: {n} worlds; 1 thread pinned to CPU {cpu} (CPU time), then 1 and {args.threads} "
              f"threads on all CPUs (wall time), {args.repeats} times, medians (speedup: of the pairs); the single "
              f"env and a batch of one (CPU time, pinned)")
        print("ceiling: the physics alone (compiled advance, no Python) on the same threads / 1 thread, in the same "
              "run: what this machine's cores give at that moment")
        print("floor: env/phys of that physics alone on 1 thread (substeps + the sync after them + gather, over the "
              "substeps): what env/phys would be with no Python at all")
        print(f"{'task':<12}{'1 thr st/s':>11}{'env/phys':>9}{'floor':>7}{f'{args.threads} thr st/s':>11}"
              f"{'speedup':>8}{'ceiling':>8}{'single us':>10}{'batch1 us':>10}")
    for name in tasks:
        # repeats x (1 thread pinned; 1 thread and `threads` threads back to back, wall time): the medians, and
        # the median of the per-pair speed-ups, so that the machine's drift between runs cancels
        ones, manys, walls, ceilings, floors = [], [], [], [], []
        for _ in range(args.repeats):
            if cpu is not None:
                os.sched_setaffinity(0, {cpu})
            ones.append(bench_batch(name, n, args.steps, 1, pinned=True))
            try:
                os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
            except (AttributeError, OSError):
                pass
            walls.append(bench_batch(name, n, args.steps, 1, pinned=False))  # the same clock as the threaded run
            manys.append(bench_batch(name, n, args.steps, args.threads, pinned=False))
            ceiling, floor = bench_physics_scaling(name, n, args.steps, args.threads)
            ceilings.append(ceiling)
            floors.append(floor)
        one = sorted(ones, key=lambda r: r["overhead_ratio"])[len(ones) // 2]
        many = sorted(manys, key=lambda r: r["steps_per_s"])[len(manys) // 2]
        one_wall = sorted(walls, key=lambda r: r["steps_per_s"])[len(walls) // 2]
        speed = statistics.median(m["steps_per_s"] / w["steps_per_s"] for m, w in zip(manys, walls))
        ceiling = statistics.median(ceilings) if None not in ceilings else None
        floor = statistics.median(floors) if None not in floors else None
        if cpu is not None:
            os.sched_setaffinity(0, {cpu})
        single = bench_single(name, max(args.steps // 2, 10), args.repeats)
        try:
            os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
        except (AttributeError, OSError):
            pass
        results["batch"]["tasks"].append({"one_thread": one, "threads": many, "one_thread_wall": one_wall,
                                          "speedup": speed, "physics_speedup": ceiling, "floor": floor})
        results["batch"]["single"].append(dict(single, task=name))
        print(f"{name:<12}{one['steps_per_s']:>11.0f}{one['overhead_ratio']:>9.2f}"
              f"{'-' if floor is None else f'{floor:.3f}':>7}{many['steps_per_s']:>11.0f}"
              f"{speed:>8.2f}{'-' if ceiling is None else f'{ceiling:.2f}':>8}{single['single']:>10.0f}"
              f"{single['batch1']:>10.0f}")
        rows.append((name, one, speed, single, floor, ceiling))
    mem = bench_memory("Insertion", args.memory) if args.memory else None
    if mem is not None:
        results["batch"]["memory"] = mem
    ant = results.get("ant") or {}
    print("\ntargets")
    print(f"{'target':<64}{'measured':>10}{'goal':>10}{'met':>5}")
    table = []
    measured = [r for r in rows if r[4] is not None and r[5] is not None]  # Throw steps world by world: none
    if measured:
        # against the floor and the ceiling measured beside each task in this run: what Python adds to the
        # compiled physics, and what share of the physics' own thread scaling the batch keeps
        over_floor = {r[0]: r[1]["overhead_ratio"] / r[4] for r in measured}
        of_ceiling = {r[0]: r[2] / r[5] for r in measured}
        worst_floor, worst_share = max(over_floor, key=over_floor.get), min(of_ceiling, key=of_ceiling.get)
        table = [(f"batch N={n}, 1 thread: env step / floor (worst: {worst_floor})",
                  f"{over_floor[worst_floor]:.2f}", "<= 1.10", over_floor[worst_floor] <= 1.10),
                 (f"batch N={n}: {args.threads}-thread speed-up / ceiling (worst: {worst_share})",
                  f"{of_ceiling[worst_share]:.2f}", ">= 0.90", of_ceiling[worst_share] >= 0.9)]
    if "overhead_ratio" in ant:
        table.insert(1, ("Ant-v5 single env: env step / physics (reference)", f"{ant['overhead_ratio']:.2f}", "-",
                         None))
    if mem is not None and "worlds_mib" in mem:
        table.append((f"memory of {mem['n']} Insertion worlds (MiB)", f"{mem['worlds_mib']:.0f}", "< 2048",
                      mem["worlds_mib"] < 2048))
    elif mem is not None:
        table.append((f"memory of {mem['n']} Insertion worlds", "error", "< 2048", False))
    for label, value, goal, ok in table:
        print(f"{label:<64}{value:>10}{goal:>10}{'-' if ok is None else ('yes' if ok else 'NO'):>5}")
    print("single env step / pre-batch single env step: measured with the pre-batch step kept in this tool up to "
          "commit 8cc08a1 (README, Batched speed)")
    print("training speed: python experiments/training_speed/training_speed.py (a separate command: it trains)")
    results["batch"]["targets"] = [{"target": t[0], "measured": t[1], "goal": t[2], "met": t[3]} for t in table]


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
