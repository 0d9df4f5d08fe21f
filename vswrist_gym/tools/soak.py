"""Soak test: many environment steps over every task, with resident memory, warnings and failures counted.

``python -m vswrist_gym.tools.soak --steps 1000000`` steps every registered task (``vswrist_gym.TASKS``) with
two agents, uniform random actions and the analytic baseline (``AnalyticAgent``, stiffness command 0), each
in two settings: the task's default config (tool mass, friction and sensor noise randomised at every reset)
and, for ``--rebuild-fraction`` of the steps, every randomisation term on, so that each reset draws new
device parameters and rebuilds the MuJoCo model (``VSWristEnv._randomize``). The steps are shared evenly
over tasks x agents; all environments are built up front and run round-robin one episode at a time, each kept
at the overall progress, so that every one of them is in use from the first round to the end and memory
measured after the warm-up covers all of them.

It records:

* resident memory (RSS, ``/proc/self/statm``) after the warm-up (``--warmup``, default the first 5 % of the
  steps) and every 5 % from there on, each time after a garbage collection and glibc's ``malloc_trim(0)``, so
  that it counts memory in use: freed blocks that the allocator keeps (heap fragmentation, which model
  rebuilds cause: glibc serves their large buffers from the heap once its dynamic mmap threshold has risen)
  are returned to the system first (``--no-trim`` leaves that out). The growth from warm-up to the end, in %,
  is the leak figure (the warm-up absorbs allocator pools, caches and first-use imports); the peak RSS of the
  whole run is printed too;
* Python warnings (every warning, recorded with ``simplefilter("always")`` so that repeats count too), and
  MuJoCo's warning counters (``WristSim.warnings()``, read at each episode end, before the reset clears them);
* divergences (``info["simulation_error"]``: the episode ends with the termination penalty) and observations
  with a NaN or inf element;
* steps per second of wall time (the machine's load counts; quote it with the date and the machine).

The exit status is 0 when memory growth is under ``--max-growth`` %, with no warning and no non-finite
observation; 1 otherwise. Divergences are reported, not failed on (the environment handles them by design).
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import platform
import sys
import time
import warnings
from dataclasses import dataclass, field
from datetime import datetime, timezone

import numpy as np

from vswrist_gym import LATEST, TASKS, newest_task_name

AGENTS = ("random", "baseline")
# every randomisation term on: the device terms rebuild the simulator at each reset (the scale ranges and
# noise levels stay those of the config files)
ALL_RANDOM = {t: {"enabled": True} for t in ("spring_K", "spring_delta0", "motor_time_constant", "link_mass",
                                             "hand_mass", "damping", "tool_mass", "friction", "latency",
                                             "sensor_noise")}
WARMUP = 0.05          # fraction of the steps before the reference memory sample
SAMPLE_EVERY = 0.05    # fraction of the steps between memory samples after the warm-up
REBUILD_FRACTION = 0.25  # share of each (task, agent) budget run with every randomisation term on
MAX_GROWTH = 5.0       # %, the largest memory growth from warm-up to end that passes


def rss_bytes() -> int:
    """Resident set size of this process now (bytes): /proc/self/statm on Linux, else the peak from
    ``resource`` (an upper bound that never falls; growth figures from it are then conservative)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return peak_rss_bytes()


@dataclass
class Cell:
    """One environment and agent, with its share of the steps and its counts."""
    task: str
    agent: str
    rebuild: bool
    budget: int
    seed: int
    steps: int = 0
    episodes: int = 0
    divergences: int = 0
    nan_obs: int = 0
    mujoco_warnings: dict = field(default_factory=dict)
    wall_s: float = 0.0
    env: object = None
    policy: object = None

    @property
    def label(self) -> str:
        return f"{self.task}/{self.agent}/{'all-random' if self.rebuild else 'default'}"


@dataclass
class SoakResult:
    steps: int
    wall_s: float
    rss_warmup: int            # bytes, after the warm-up
    rss_end: int               # bytes, at the end
    rss_samples: list          # (steps so far, bytes) after the warm-up
    rss_peak: int              # bytes, the largest resident set of the process (without trims)
    trimmed: bool              # samples taken after malloc_trim
    python_warnings: list      # "Category: message" of every warning, in order
    cells: list

    @property
    def growth_pct(self) -> float:
        return 100.0 * (self.rss_end - self.rss_warmup) / self.rss_warmup

    @property
    def mujoco_warnings(self) -> dict:
        out: dict[str, int] = {}
        for c in self.cells:
            for k, v in c.mujoco_warnings.items():
                out[k] = out.get(k, 0) + v
        return out

    @property
    def divergences(self) -> int:
        return sum(c.divergences for c in self.cells)

    @property
    def nan_obs(self) -> int:
        return sum(c.nan_obs for c in self.cells)

    def passed(self, max_growth: float = MAX_GROWTH) -> bool:
        return (self.growth_pct < max_growth and not self.python_warnings and not self.mujoco_warnings
                and self.nan_obs == 0)


def _check_args(steps, tasks, warmup, rebuild_fraction) -> None:
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps must be a positive integer, got {steps!r}")
    unknown = [t for t in tasks if t not in TASKS]
    if not tasks or unknown:
        raise ValueError(f"tasks must be a non-empty list of {list(TASKS)}, got {list(tasks)!r}")
    if not (isinstance(warmup, (int, float)) and 0.0 < warmup < 1.0):
        raise ValueError(f"warmup must be a fraction of the steps in (0, 1), got {warmup!r}")
    if not (isinstance(rebuild_fraction, (int, float)) and 0.0 <= rebuild_fraction <= 1.0):
        raise ValueError(f"rebuild_fraction must be in [0, 1], got {rebuild_fraction!r}")
    both = 0.0 < rebuild_fraction < 1.0
    if steps // (len(tasks) * len(AGENTS)) < (2 if both else 1):
        raise ValueError(f"steps = {steps} is too few for {len(tasks)} task(s) x {len(AGENTS)} agents"
                         f"{' x 2 settings' if both else ''}")


def _plan(steps: int, tasks, rebuild_fraction: float, seed: int) -> list[Cell]:
    """Budgets: steps shared evenly over tasks x agents (the remainder to the first pairs), each pair's share
    split between the default config and the all-random one."""
    pairs = [(t, a) for t in tasks for a in AGENTS]
    base, extra = divmod(steps, len(pairs))
    cells = []
    for i, (task, agent) in enumerate(pairs):
        share = base + (1 if i < extra else 0)
        rebuild = int(round(share * rebuild_fraction))
        if 0.0 < rebuild_fraction < 1.0:  # both settings run, however few the steps
            rebuild = min(max(rebuild, 1), share - 1)
        for flag, budget in ((False, share - rebuild), (True, rebuild)):
            if budget > 0:
                cells.append(Cell(task, agent, flag, budget, seed=seed + len(cells)))
    return cells


def _build(cell: Cell) -> None:
    import gymnasium as gym

    from vswrist_gym.agents.analytic import AnalyticAgent

    kwargs = {"config": {"randomize": ALL_RANDOM}} if cell.rebuild else {}
    env = gym.make(LATEST[cell.task], **kwargs)
    if cell.agent == "random":
        rng = np.random.default_rng(cell.seed)
        low, high, shape = env.action_space.low, env.action_space.high, env.action_space.shape
        cell.policy = lambda obs, start: rng.uniform(low, high, shape).astype(np.float32)
    else:
        agent = AnalyticAgent(env)
        cell.policy = lambda obs, start: agent.predict(obs, episode_start=start, deterministic=True)[0]
    cell.env = env


def _add_mujoco_warnings(cell: Cell) -> None:
    for name, n in cell.env.unwrapped.sim.warnings().items():
        cell.mujoco_warnings[name] = cell.mujoco_warnings.get(name, 0) + n


def _episode(cell: Cell, first: bool) -> int:
    """Run one episode (or what is left of the cell's budget); returns the steps taken."""
    env = cell.env
    t0 = time.perf_counter()
    obs, _ = env.reset(seed=cell.seed) if first else env.reset()
    start = True
    n = 0
    while cell.steps + n < cell.budget:
        obs, _, terminated, truncated, info = env.step(cell.policy(obs, start))
        start = False
        n += 1
        if not np.isfinite(obs).all():
            cell.nan_obs += 1
        if "simulation_error" in info:
            cell.divergences += 1
        if terminated or truncated:
            break
    _add_mujoco_warnings(cell)  # before the next reset clears MuJoCo's counters
    cell.steps += n
    cell.episodes += 1
    cell.wall_s += time.perf_counter() - t0
    return n


def _malloc_trim() -> None:
    """Return the C heap's free pages to the system (glibc); nothing elsewhere."""
    try:
        import ctypes
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):  # not glibc (musl, macOS, Windows): RSS then includes freed blocks
        pass


def _rss_now(trim: bool = True) -> int:
    gc.collect()
    if trim:
        _malloc_trim()
    return rss_bytes()


def peak_rss_bytes() -> int:
    """The largest resident set of this process so far (bytes)."""
    import resource
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024  # bytes on macOS, KiB on Linux


def run_soak(steps: int = 1_000_000, tasks=TASKS, seed: int = 0, warmup: float = WARMUP,
             rebuild_fraction: float = REBUILD_FRACTION, progress: bool = True, trim: bool = True) -> SoakResult:
    """Run the soak (see the module docstring) and return its figures. ``trim=False``: memory samples without
    ``malloc_trim`` (RSS as the allocator leaves it, fragmentation included)."""
    tasks = list(tasks)
    _check_args(steps, tasks, warmup, rebuild_fraction)
    cells = _plan(steps, tasks, rebuild_fraction, seed)
    warm_at = int(math.ceil(warmup * steps))
    every = max(1, int(round(SAMPLE_EVERY * steps)))
    from vswrist_gym.agents.progress import bar as progress_bar

    # on a terminal, with tqdm, unless --no-progress or vswrist --quiet
    bar = progress_bar(total=steps, desc="soak", unit="step", disable=not progress, smoothing=0.05, mininterval=1.0)
    done = 0
    rss_warm, samples, next_sample = None, [], None
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            for c in cells:
                _build(c)
            first = True
            while done < steps:
                # an episode for each environment not ahead of the overall progress, so that every one of
                # them (the short all-random budgets too) runs from the warm-up to the end
                progress_now = done / steps
                for c in cells:
                    if c.steps < c.budget and (first or c.steps / c.budget <= progress_now):
                        n = _episode(c, first)
                        done += n
                        bar.update(n)
                first = False
                # samples between rounds, so that every environment is between episodes
                if rss_warm is None and done >= warm_at:
                    rss_warm = _rss_now(trim)
                    samples.append((done, rss_warm))
                    next_sample = done + every
                elif next_sample is not None and (done >= next_sample or done >= steps):
                    samples.append((done, _rss_now(trim)))
                    next_sample = done + every
        finally:
            bar.close()
            for c in cells:
                if c.env is not None:
                    c.env.close()
    wall = time.perf_counter() - t0
    rss_end = samples[-1][1]
    for c in cells:
        c.env = c.policy = None
    return SoakResult(steps=done, wall_s=wall, rss_warmup=rss_warm, rss_end=rss_end, rss_samples=samples,
                      rss_peak=peak_rss_bytes(), trimmed=trim,
                      python_warnings=[f"{w.category.__name__}: {w.message}" for w in caught], cells=cells)


def format_result(r: SoakResult, max_growth: float = MAX_GROWTH) -> str:
    mib = 1 << 20
    lines = [f"{'task':<10} {'agent':<9} {'randomisation':<13} {'steps':>8} {'episodes':>8} {'diverged':>8} "
             f"{'NaN obs':>7} {'MuJoCo warn':>11} {'steps/s':>8}"]
    for c in r.cells:
        mw = sum(c.mujoco_warnings.values())
        lines.append(f"{c.task:<10} {c.agent:<9} {'all (rebuild)' if c.rebuild else 'default':<13} {c.steps:>8} "
                     f"{c.episodes:>8} {c.divergences:>8} {c.nan_obs:>7} {mw:>11} {c.steps / c.wall_s:>8.0f}")
    lines.append("")
    lines.append(f"steps {r.steps:,} in {r.wall_s:.0f} s ({r.steps / r.wall_s:.0f} steps/s wall, environment "
                 f"building included)")
    how = "in use (after gc and malloc_trim)" if r.trimmed else "after gc, not trimmed"
    lines.append(f"RSS after warm-up ({r.rss_samples[0][0]:,} steps) {r.rss_warmup / mib:.1f} MiB, at the end "
                 f"{r.rss_end / mib:.1f} MiB: growth {r.growth_pct:+.2f} % (limit {max_growth:g} %); {how}; "
                 f"peak RSS of the process {r.rss_peak / mib:.1f} MiB")
    lines.append("RSS samples (steps: MiB): " + ", ".join(f"{s:,}: {b / mib:.1f}" for s, b in r.rss_samples))
    lines.append(f"Python warnings: {len(r.python_warnings)}; MuJoCo warnings: {r.mujoco_warnings or 0}; "
                 f"divergences: {r.divergences}; non-finite observations: {r.nan_obs}")
    for w in dict.fromkeys(r.python_warnings):  # each distinct message once
        lines.append(f"  {r.python_warnings.count(w)} x {w}")
    lines.append(f"verdict: {'PASS' if r.passed(max_growth) else 'FAIL'}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m vswrist_gym.tools.soak",
                                description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("--steps", type=int, default=1_000_000, help="environment steps in all (default 1,000,000)")
    p.add_argument("--tasks", nargs="+", default=list(TASKS), type=newest_task_name,
                   help=f"short names or full ids (default all: {' '.join(TASKS)})")
    p.add_argument("--seed", type=int, default=0, help="first seed (each environment gets the next one)")
    p.add_argument("--warmup", type=float, default=WARMUP,
                   help=f"fraction of the steps before the reference memory sample (default {WARMUP})")
    p.add_argument("--rebuild-fraction", type=float, default=REBUILD_FRACTION,
                   help="share of each task and agent's steps with every randomisation term on (model rebuilt "
                        f"at each reset; default {REBUILD_FRACTION}; 1: the rebuild path alone)")
    p.add_argument("--max-growth", type=float, default=MAX_GROWTH,
                   help=f"largest memory growth from warm-up to end that passes, in %% (default {MAX_GROWTH:g})")
    p.add_argument("--no-trim", action="store_true",
                   help="memory samples without malloc_trim (RSS with the allocator's free blocks)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if not (math.isfinite(args.max_growth) and args.max_growth > 0):
        print(f"soak: error: --max-growth must be a positive percentage, got {args.max_growth}", file=sys.stderr)
        return 2
    try:
        _check_args(args.steps, args.tasks, args.warmup, args.rebuild_fraction)
    except ValueError as exc:
        print(f"soak: error: {exc}", file=sys.stderr)
        return 2
    started = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    r = run_soak(args.steps, args.tasks, args.seed, args.warmup, args.rebuild_fraction,
                 progress=not args.no_progress, trim=not args.no_trim)
    try:
        load = " load average %.2f %.2f %.2f at the end;" % os.getloadavg()
    except OSError:
        load = ""
    print(f"soak started {started}; {platform.python_implementation()} {platform.python_version()}, "
          f"{os.cpu_count()} CPUs;{load} seed {args.seed}")
    print(format_result(r, args.max_growth))
    return 0 if r.passed(args.max_growth) else 1


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
