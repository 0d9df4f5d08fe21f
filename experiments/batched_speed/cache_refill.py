"""What the physics' eviction of the caches costs a batch step's Python: the CPU time of a step outside the compiled
advance, measured twice on one thread pinned to CPU 1: after the real physics (the worlds' MjData have just
streamed through the caches), and with the physics replaced by a copy of its last output (the step's Python then
finds its code, NumPy's internals and its arrays still cached). Both runs take the same actions and the same
steps (no resets in the window); the second run's physics is a memcpy, so its observations repeat and an event
the physics would have found (Throw's release) is not found: the Python's work is nearly, not exactly, the same.

    python experiments/batched_speed/cache_refill.py [--tasks LoadHold Hammer Throw] [--worlds 64] [--steps 40]

Prints, per task, the median over ``--pairs`` alternating pairs: the Python per step after the physics and warm,
their ratio, the advance per step, and env/phys (the step over the time inside ``mj_step``) as measured and as it
would be with the warm Python; and, in the same run, the floor (``vswrist bench-env``'s: the compiled advance
alone, no Python) and both env/phys over it, the figure of the batch's target (<= 1.10). Last, the same effect
in isolation: four small array calls (``_after_native``'s status tests on 64 worlds) timed warm and right after a
sweep of 64 MB."""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

import vswrist_gym  # noqa: F401
from vswrist_gym import LATEST
from vswrist_gym import batch_sim as BS
from vswrist_gym.envs.batch import VSWristVectorEnv
from vswrist_gym.tools.bench import bench_physics_scaling

_real_advance = BS.BatchSim.advance
_state = {"replay": False, "G": None, "status": None, "advance": 0.0}


def _advance(self, worlds, theta, status, seconds=None, out=None):
    """The compiled advance, or (``replay``) a copy of its last output into ``out`` and ``status``."""
    t0 = time.process_time()
    try:
        if _state["replay"] and _state["G"] is not None and len(_state["G"]) == len(out):
            out[:] = _state["G"]
            status[:] = _state["status"]
            return int((status != 0).sum())
        r = _real_advance(self, worlds, theta, status, seconds, out)
        _state["G"], _state["status"] = out.copy(), status.copy()
        return r
    finally:
        _state["advance"] += time.process_time() - t0


def run(env_id: str, worlds: int, steps: int, replay: bool) -> tuple[float, float, float]:
    """(Python ms per step, advance ms per step, mj_step ms per step) of ``steps`` steps after 5 warm-up steps."""
    v = VSWristVectorEnv(env_id, worlds, threads=1)
    v.reset(seed=0)
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (steps + 5, worlds) + v.single_action_space.shape).astype(np.float32)
    for a in acts[:5]:
        v.step(a)
    _state["replay"], _state["advance"] = replay, 0.0
    v.physics_seconds = 0.0
    t0 = time.process_time()
    for a in acts[5:]:
        v.step(a)
    dt = time.process_time() - t0
    mj = v.physics_seconds
    _state["replay"] = False
    v.close()
    return 1e3 * (dt - _state["advance"]) / steps, 1e3 * _state["advance"] / steps, 1e3 * mj / steps


def isolated(reps: int = 200) -> tuple[float, float]:
    """Median microseconds of four small array calls, warm and right after a 64 MB sweep."""
    status = np.zeros(64, dtype=np.int32)
    big = np.ones(8_000_000)

    def calls() -> float:
        t0 = time.perf_counter()
        np.flatnonzero((status != 0) & (status != 2)).tolist()
        _ = status == 2
        return time.perf_counter() - t0

    warm = [calls() for _ in range(reps)]
    cold = []
    for _ in range(reps // 4):
        big *= 1.0
        cold.append(calls())
    return 1e6 * float(np.median(warm)), 1e6 * float(np.median(cold))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", nargs="+", default=["LoadHold", "Hammer", "Throw"])
    ap.add_argument("--worlds", type=int, default=64)
    ap.add_argument("--steps", type=int, default=40, help="timed steps (keep under the shortest episode)")
    ap.add_argument("--pairs", type=int, default=3)
    args = ap.parse_args(argv)
    if hasattr(os, "sched_setaffinity") and (os.cpu_count() or 1) > 1:
        os.sched_setaffinity(0, {1})
    print(f"{args.worlds} worlds, 1 thread, {args.steps} steps, median of {args.pairs} pairs; ms per step")
    print(f"{'task':12s} {'py after':>9s} {'py warm':>8s} {'ratio':>6s} {'advance':>8s} {'env/phys':>9s} "
          f"{'warm':>6s} {'floor':>6s} {'env/floor':>10s} {'warm':>6s}")
    for name in args.tasks:
        env_id = LATEST.get(name, name)
        BS.BatchSim.advance = _real_advance
        _, floor = bench_physics_scaling(name, args.worlds, 64 * args.worlds, 2)
        BS.BatchSim.advance = _advance
        cold, warm, adv, mj = [], [], [], []
        for _ in range(args.pairs):
            c, a, m = run(env_id, args.worlds, args.steps, replay=False)
            w, _, _ = run(env_id, args.worlds, args.steps, replay=True)
            cold.append(c), warm.append(w), adv.append(a), mj.append(m)
        c, w, a, m = (float(np.median(x)) for x in (cold, warm, adv, mj))
        after, warm = (a + c) / m, (a + w) / m
        print(f"{name:12s} {c:9.3f} {w:8.3f} {c / w:6.2f} {a:8.2f} {after:9.3f} {warm:6.3f} {floor:6.3f} "
              f"{after / floor:10.3f} {warm / floor:6.3f}")
    w, c = isolated()
    print(f"four small array calls: {w:.1f} us warm, {c:.1f} us right after a 64 MB sweep")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
