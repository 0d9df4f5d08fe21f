"""A search's samples in one table per task, from the records that `vswrist sweep` wrote in search mode (copied
to FOLDER/<Task>.json): experiments/tuned_stiffness/NOTES.md (`search_ppo_stiffness.yaml`, records in
experiments/tuned_stiffness/search), section 7b (`search_ppo_hammer.yaml`, in experiments/hammer_stiffness_tuned/search)
and section 5d (`search_sac_hammer.yaml`, SAC, in experiments/sac_hammer_searched/search):

    python experiments/tuned_stiffness/search_table.py [experiments/tuned_stiffness/search]

Every sample with the steps it reached before ASHA stopped it and its last periodic-evaluation return (10
episodes, training seed 100); the best sample at the full budget is the entry the search wrote.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path


def main(argv=None) -> int:
    folder = Path((argv or sys.argv[1:] or ["experiments/tuned_stiffness/search"])[0])
    for path in sorted(folder.glob("*.json")):
        doc = json.loads(path.read_text())
        trials = sorted(doc["trials"].values(), key=lambda t: -t["eval_return"])
        full = max(t["timesteps"] for t in trials)
        print(f"\n{path.stem}: {len(trials)} samples, {sum(t['timesteps'] >= full for t in trials)} reached "
              f"{full:,} steps\n")
        keys = list(trials[0]["config"])  # the searched keys, in the search file's order
        names = [k.split("__")[-1] if k != "policy_kwargs" else "log_std_init" for k in keys]
        print("| eval return | steps | " + " | ".join(names) + " |")
        print("|---|---|" + "---|" * len(keys))
        for t in trials:
            c = t["config"]
            cells = []
            for k in keys:
                v = c[k]
                if k == "policy_kwargs":
                    v = re.search(r"log_std_init=(-?[\d.]+)", v).group(1)
                elif k == "learning_rate":
                    v = f"{v:.2g}"
                cells.append(str(v))
            print(f"| {t['eval_return']:.1f} | {t['timesteps']:,} | " + " | ".join(cells) + " |")
        if "frame_stack" in keys:
            for k in (1, 4):
                at_full = [t["eval_return"] for t in trials
                           if t["config"]["frame_stack"] == k and t["timesteps"] >= full]
                print(f"\nframe_stack {k}: {sum(t['config']['frame_stack'] == k for t in trials)} samples, "
                      f"{len(at_full)} at the full budget" + (f", best {max(at_full):.1f}" if at_full else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
