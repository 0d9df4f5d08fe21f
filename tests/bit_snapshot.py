"""Bit-level snapshot of single-env and batch trajectories, to show that a change leaves every number as it was
(on one machine): ``python tests/bit_snapshot.py save before.npz`` on the old code, then
``python tests/bit_snapshot.py check before.npz`` on the new; prints IDENTICAL or the largest difference per
trajectory and exits 1 if any differs. Every task of ``vswrist_gym.LATEST``: the single env with seeds 0 and 1
and a batch of 8 worlds (one thread), 130 steps of random actions each, short episodes (0.6 s; Hammer 0.3 s) so
that resets happen; observations and rewards."""

from __future__ import annotations

import sys

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401  (registers the environments)
from vswrist_gym import LATEST

USAGE = "usage: python tests/bit_snapshot.py save|check FILE.npz"


def snapshot(tasks=None, steps: int = 130, worlds: int = 8) -> dict[str, np.ndarray]:
    """Per trajectory name (``Task/seed/single``, ``Task/batch``), its observations and rewards, concatenated."""
    out = {}
    for task, eid in LATEST.items():
        if tasks is not None and task not in tasks:
            continue
        config = {"episode_s": 0.6 if task != "Hammer" else 0.3}
        for seed in (0, 1):
            env = gym.make(eid, config=config)
            rng = np.random.default_rng(seed)
            o, _ = env.reset(seed=seed)
            rows = [o.astype(np.float64)]
            for _ in range(steps):
                o, r, te, tr, _info = env.step(rng.uniform(-1, 1, env.action_space.shape))
                rows.append(np.concatenate([o, [r]]))
                if te or tr:
                    o, _ = env.reset()
                    rows.append(o.astype(np.float64))
            out[f"{task}/{seed}/single"] = np.concatenate(rows)
            env.close()
        venv = gym.make_vec(eid, num_envs=worlds, vectorization_mode="vector_entry_point", threads=1, config=config)
        rng = np.random.default_rng(5)
        o, _ = venv.reset(seed=3)
        rows = [o.ravel()]
        for _ in range(steps):
            o, r, te, tr, _info = venv.step(rng.uniform(-1, 1, venv.action_space.shape))
            rows += [o.ravel(), r]
        out[f"{task}/batch"] = np.concatenate(rows)
        venv.close()
    return out


def compare(new: dict[str, np.ndarray], ref) -> list[str]:
    """One line per trajectory: IDENTICAL, or the largest absolute difference (or 'shape')."""
    lines = []
    for k, v in new.items():
        if k not in ref:
            lines.append(f"{k} MISSING from the reference")
            continue
        w = ref[k]
        if v.shape != w.shape:
            lines.append(f"{k} DIFF shape {w.shape} -> {v.shape}")
        elif np.array_equal(v, w):
            lines.append(f"{k} IDENTICAL")
        else:
            lines.append(f"{k} DIFF max {np.max(np.abs(v - w))}")
    return lines


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] not in ("save", "check"):
        print(USAGE, file=sys.stderr)
        return 2
    mode, path = argv
    if mode == "save":
        np.savez(path, **snapshot())
        return 0
    try:
        ref = np.load(path)
    except OSError as exc:
        print(f"bit_snapshot: error: cannot read {path} ({exc})", file=sys.stderr)
        return 2
    lines = compare(snapshot(), ref)
    print("\n".join(lines))
    return 0 if all(line.endswith("IDENTICAL") for line in lines) else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
