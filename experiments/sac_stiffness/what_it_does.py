"""What SAC does with the stiffness on Drill's stiffness track (experiments/sac_stiffness/NOTES.md), from the committed
per-episode metrics and the trace of `vswrist sweep experiments/sac_stiffness/sac_stiffness.yaml`:

    python3 experiments/sac_stiffness/what_it_does.py [experiments/sac_stiffness/Drill]

Per seed: the paired difference in return to the stiffest constant (analytic +1.00, Drill's best fixed command) on
the same 200 episodes, and the means of the stiffness used, the elastic (preload) energy, the RMS posture error and
success; then the traced episode (seed 0, episode 0): the internal torque while the drill engages (contact force
above 0) and while it does not.
"""

import csv
import json
import statistics as st
import sys
from pathlib import Path

d = Path(sys.argv[1] if len(sys.argv) > 1 else "experiments/sac_stiffness/Drill")


def per_seed(agent_dir: str) -> dict[int, list[dict]]:
    out: dict[int, list[dict]] = {}
    for r in csv.DictReader(open(d / "eval" / agent_dir / "metrics.csv")):
        out.setdefault(int(r["seed"]), []).append(r)
    return out


sac, const = per_seed("sac"), per_seed("analytic_+1.00")
keys = ("stiffness_used", "elastic_energy", "rms_posture_error", "success")
print("| agent | seed | return | paired vs +1.00 | " + " | ".join(keys) + " |")
print("|---|---|---|---|" + "---|" * len(keys))
for name, runs in (("SAC", sac), ("analytic +1.00", const)):
    for seed, eps in sorted(runs.items()):
        c = {(r["reset_seed"]): float(r["return"]) for r in const[seed]}
        paired = st.mean(float(r["return"]) - c[r["reset_seed"]] for r in eps)
        vals = " | ".join(f"{st.mean(float(r[k]) for r in eps):.3f}" for k in keys)
        print(f"| {name} | {seed} | {st.mean(float(r['return']) for r in eps):+.1f} | {paired:+.1f} | {vals} |")

traces = json.loads((d / "summary.json").read_text())["traces"]
for label in ("SAC", "analytic:+1.00"):
    tr = traces[label]
    on = [lam for lam, f in zip(tr["lam"], tr["contact_force"]) if f > 0]
    off = [lam for lam, f in zip(tr["lam"], tr["contact_force"]) if f <= 0]
    t_on = [t for t, f in zip(tr["time"], tr["contact_force"]) if f > 0]
    span = f"{t_on[0]:.2f}-{t_on[-1]:.2f} s" if t_on else "never"
    print(f"{label}: drill engaged {span}; internal torque engaged {st.mean(on) if on else float('nan'):.1f} N m "
          f"(min {min(on) if on else float('nan'):.1f}), not engaged {st.mean(off) if off else float('nan'):.1f} "
          f"N m (min {min(off) if off else float('nan'):.1f}, max {max(off) if off else float('nan'):.1f})")
