"""Old against new Polish and Hammer episodes: record them with one code tree, compare two recordings.

    PYTHONPATH=<old tree> python experiments/contact_meter_equivalence/contact_meter_equivalence.py record old.npz
    PYTHONPATH=<new tree> python experiments/contact_meter_equivalence/contact_meter_equivalence.py record new.npz
    python experiments/contact_meter_equivalence/contact_meter_equivalence.py compare old.npz new.npz

The protocol is ``tests/reference/record.py``'s (random actions from a fixed generator and the analytic baseline,
short episodes with resets, a divergence forced before step 47) for seeds 3, 11, 21, 42, latency randomisation on
and off, 90 steps (Polish) and 150 (Hammer, 0.6 s episodes), plus Hammer's strike entries of ``info``. Used to
show that moving the per-substep contact measurements into the ``vswrist.contact`` plugin changed no episode
(``compare`` prints the largest difference per quantity).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HAMMER_KEYS = ("struck", "impact_speed", "impact_time", "impact_offset", "rigid_speed")


def record_all(out: str) -> None:
    import gymnasium as gym

    import vswrist_gym

    sys.path.insert(0, str(Path(vswrist_gym.__file__).resolve().parents[1] / "tests" / "reference"))
    import record

    base_keys = record.INFO_KEYS
    data = {}
    for task in ("Polish", "Hammer"):
        record.INFO_KEYS = base_keys + (HAMMER_KEYS if task == "Hammer" else ())
        for seed in (3, 11, 21, 42):
            for policy in ("random", "analytic"):
                for latency in (True, False):
                    cfg = {"episode_s": 0.6, "randomize": {"latency": {"enabled": latency}}}
                    env = gym.make(f"VSWrist/{task}-v0", config=cfg)
                    rows = record.run(env, lambda e: e.unwrapped.data, task, seed, policy,
                                      steps=150 if task == "Hammer" else 90)
                    for k, v in rows.items():
                        data[f"{task}/{seed}/{policy}/{latency}/{k}"] = v
    np.savez(out, **data)
    print(f"{out}: {len(data)} arrays, recorded with {vswrist_gym.__file__}")


def compare(a_path: str, b_path: str) -> float:
    a, b = np.load(a_path), np.load(b_path)
    if sorted(a.files) != sorted(b.files):
        raise SystemExit("the recordings hold different runs")
    worst: dict[str, float] = {}
    for k in a.files:
        x, y = a[k], b[k]
        if x.shape != y.shape:
            raise SystemExit(f"{k}: shapes {x.shape} and {y.shape} differ (an episode ended elsewhere)")
        same = (x == y) | (np.isnan(x) & np.isnan(y))  # inf (a diverged step's loop closure) equals inf
        with np.errstate(invalid="ignore"):
            d = np.where(same, 0.0, np.abs(x - y))
        key = f"{k.split('/')[0]} {k.split('/')[-1]}"
        worst[key] = max(worst.get(key, 0.0), float(np.nanmax(d)) if d.size else 0.0, float(np.isnan(d).any()))
    for k, v in sorted(worst.items()):
        print(f"{k:32s} {v:.3g}")
    m = max(worst.values())
    print(f"largest difference: {m:.3g} ({len(a.files)} arrays)")
    return m


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "record":
        record_all(sys.argv[2])
    elif len(sys.argv) == 4 and sys.argv[1] == "compare":
        compare(sys.argv[2], sys.argv[3])
    else:
        raise SystemExit(__doc__)
