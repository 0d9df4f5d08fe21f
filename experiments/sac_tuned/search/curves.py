"""The search's learning curves, from the run directories' periodic evaluations (eval/evaluations.npz: 5
episodes, deterministic policy, reset seeds seed + 10,000 + i, never the protocol's 1,000,000+).

    python experiments/sac_tuned/search/curves.py runs/tune/*      (the runs of the commands in experiments/README.md)
"""

import sys

import numpy as np

print("| run | steps | first evaluation | lowest | last at <= 50,000 | last 3 evaluations | last |")
print("|---|---|---|---|---|---|---|")
for d in sys.argv[1:]:
    try:
        e = np.load(f"{d}/eval/evaluations.npz")
    except OSError:
        continue
    r, t = e["results"].mean(1), e["timesteps"]
    at50k = f"{r[t <= 50000][-1]:+.1f}" if t[-1] >= 50000 else ""  # blank for a run stopped before 50,000 steps
    print(f"| {d.rstrip('/').split('/')[-1]} | {t[-1]:,} | {r[0]:+.1f} | {r.min():+.1f} | {at50k} | "
          f"{r[-3:].mean():+.1f} | {r[-1]:+.1f} |")
