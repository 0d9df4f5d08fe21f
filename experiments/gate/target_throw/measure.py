"""Target-speed throw, in the probe env (target_env.py): the five constants, the target rule, the best open-loop
posture trim per target and the gate's posture feedback (IntegralTrim), paired on probe episodes.
The best constant is chosen on training seeds 100-199; the rule and the trims are lookups from the observed target
to a stiffness schedule or a 3-segment FE trim fitted on training seeds 100-139 (collect.py's ratios: the physics is
Throw-v0's to the digit, the target drawn after it); the feedback's rate is chosen on training seeds 100-139.
Usage: measure.py LO HI TOL N   (probe episodes 1000 .. 1000+N-1)"""
import os, sys, numpy as np
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import vswrist_gym  # noqa: F401
from target_env import register_probe
from vswrist_gym.tools.gate import IntegralTrim, feedback_kwargs
import measure_lib as M
lo, hi, tol, N = float(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
EID = register_probe({"target_ratio": [lo, hi], "target_tolerance": tol})
PROBE, SELECT = [1000 + i for i in range(N)], list(range(100, 200))
const = {s: M.returns(EID, lambda e, t, s=s: M.constant_policy(e, s), PROBE) for s in (-1.0, -0.5, 0.0, 0.5, 1.0)}
const_tr = {s: M.returns(EID, lambda e, t, s=s: M.constant_policy(e, s), SELECT).mean() for s in const}
best = max(const_tr, key=const_tr.get)
base = const[best]
print(f"targets U[{lo}, {hi}] x rigid, tent {tol}; probe episodes {PROBE[0]}-{PROBE[-1]}")
print("constants, probe mean (training 100-199 mean): " + "  ".join(f"{s:+.1f}: {v.mean():.2f} ({const_tr[s]:.2f})"
      for s, v in const.items()) + f"; best (training) {best:+.1f}")
rule = M.rule_factory(lo, hi, tol)
H, se = M.paired(M.returns(EID, rule, PROBE), base)
g, names = rule.table
print(f"rule (target -> schedule): headroom {H:+.2f} (se {se:.2f}, z {H/se:.1f}); its table: "
      + " ".join(f"{x:.2f}:{k}" for x, k in zip(g[::5], names[::5])))
res = {"action_mode": "residual", "residual": {"posture_scale": 0.15, "stiffness_scale": 0.0, "stiffness_nominal": best}}
if os.path.exists(os.path.join(M.HERE, f"ratios_trims{best:+.1f}.npz")):
    zero = M.returns(EID, lambda e, t: M.trim_policy(e, (0.0, 0.0, 0.0)), PROBE, {"config": res})
    print(f"  zero residual - constant: {np.abs(zero - base).max():.4f} (max |diff|)")
    g, gse = M.paired(M.returns(EID, M.trim_factory(best, lo, hi, tol), PROBE, {"config": res}), base)
    print(f"open-loop FE trim per target at s = {best:+.1f}: gain {g:+.2f} (se {gse:.2f}), share {g/H:.2f}")
fb = feedback_kwargs(best)
ctr = M.returns(EID, lambda e, t: M.constant_policy(e, best), M.TRAIN)
ktr = {k: M.paired(M.returns(EID, lambda e, t, k=k: IntegralTrim(e, k), M.TRAIN, fb, sb3=True), ctr)[0]
       for k in (0.0, 2.0, 5.0, 10.0, 20.0)}
kb = max(ktr, key=ktr.get)
g, gse = M.paired(M.returns(EID, lambda e, t: IntegralTrim(e, kb), PROBE, fb, sb3=True), base)
print("posture feedback (IntegralTrim), training gains " + " ".join(f"{k:g}/s:{v:+.2f}" for k, v in ktr.items()) +
      f"; chosen {kb:g}/s: probe gain {g:+.2f} (se {gse:.2f}), share {g/H:.2f} [{(g-1.96*gse)/H:.2f}, {(g+1.96*gse)/H:.2f}]")
