"""The PPO stiffness-track search in one table per task (results/README.md section 9), from the records that
`vswrist sweep vswrist_gym/configs/sweeps/search_ppo_stiffness.yaml` wrote (copied to
results/tuned_stiffness/search/<Task>.json):

    python results/search_table.py [results/tuned_stiffness/search]

Every sample with the steps it reached before ASHA stopped it and its last periodic-evaluation return (10
episodes, training seed 100); the best sample at the full budget is the entry the search wrote.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path


def main(argv=None) -> int:
    folder = Path((argv or sys.argv[1:] or ["results/tuned_stiffness/search"])[0])
    for path in sorted(folder.glob("*.json")):
        doc = json.loads(path.read_text())
        trials = sorted(doc["trials"].values(), key=lambda t: -t["eval_return"])
        full = max(t["timesteps"] for t in trials)
        print(f"\n{path.stem}: {len(trials)} samples, {sum(t['timesteps'] >= full for t in trials)} reached "
              f"{full:,} steps\n")
        print("| eval return | steps | learning_rate | ent_coef | gamma | n_epochs | frame_stack | log_std_init |")
        print("|---|---|---|---|---|---|---|---|")
        for t in trials:
            c = t["config"]
            log_std = re.search(r"log_std_init=(-?[\d.]+)", c["policy_kwargs"]).group(1)
            print(f"| {t['eval_return']:.1f} | {t['timesteps']:,} | {c['learning_rate']:.2g} | {c['ent_coef']} | "
                  f"{c['gamma']} | {c['n_epochs']} | {c['frame_stack']} | {log_std} |")
        for k in (1, 4):
            at_full = [t["eval_return"] for t in trials if t["config"]["frame_stack"] == k and t["timesteps"] >= full]
            print(f"\nframe_stack {k}: {sum(t['config']['frame_stack'] == k for t in trials)} samples, "
                  f"{len(at_full)} at the full budget" + (f", best {max(at_full):.1f}" if at_full else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
