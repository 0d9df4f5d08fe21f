"""Did frame stacking help? The tuned PPO entry against the same entry with the other `frame_stack`, per task, on
the same evaluation episodes (experiments/tuned_stiffness/NOTES.md).

    python experiments/tuned_stiffness/frame_stack_effect.py experiments/tuned_stiffness/tuned_stiffness.yaml \
        experiments/tuned_stiffness_fs1/tuned_stiffness_fs1.yaml

Both are `vswrist sweep` grid files with the same seeds and episodes whose PPO entries differ only in
`frame_stack`; their outputs (`out:`) are compared task by task. Episodes are paired by (training seed, reset
seed): per seed the mean difference, then the mean and the Student-t 95 % interval over seeds
(`tools.contribution`'s pairing).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from vswrist_gym.sweep.spec import load_sweep
from vswrist_gym.tools.contribution import contribution


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("a", help="grid sweep file of the tuned entries")
    p.add_argument("b", help="grid sweep file of the same entries with the other frame_stack")
    args = p.parse_args(argv)
    sa, sb = load_sweep(args.a), load_sweep(args.b)
    a, b = sa.out, sb.out
    print("| task | seeds x episodes | tuned entry | return | other frame_stack | return | paired difference "
          "(tuned - other) | verdict |")
    print("|---|---|---|---|---|---|---|---|")
    for env_id in sb.env_ids:
        task = env_id.split("/")[-1].rsplit("-v", 1)[0]
        stacks = [s.entries[("ppo", env_id)].get("frame_stack", 1) for s in (sa, sb)]
        r = contribution(a / task / "eval" / "ppo" / "metrics.json", b / task / "eval" / "ppo" / "metrics.json")
        c = r["contribution"]
        verdict = ("no interval" if math.isnan(c["low"]) else "tuned entry better" if c["low"] > 0
                   else "other better" if c["high"] < 0 else "not distinguishable")
        n = len(r["seeds"])
        print(f"| {task} | {n} x {r['episodes'] // n} | frame_stack {stacks[0]} | {r['full']['mean']:.1f} | "
              f"frame_stack {stacks[1]} | {r['posture_only']['mean']:.1f} | "
              f"{c['mean']:+.1f} [{c['low']:+.1f}, {c['high']:+.1f}] | {verdict} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
