"""Release speed / rigid bound, per episode, of a family of agents on Throw-v0's counter-movement (the physics of
the target-speed throw: the target changes only the reward). Training seeds 100-139 and probe episodes 1000-1059.
Usage: collect.py stiffness|trims S0  -> ratios_<what>.npz"""
import sys, itertools, numpy as np, gymnasium as gym
import vswrist_gym
from vswrist_gym.tools.probe import constant_policy, adaptive_policy, within, trim_policy
SEEDS = list(range(100, 140)) + list(range(1000, 1060))
def ratios(env, fac):
    out = []
    for seed in SEEDS:
        pol = fac(env); o, _ = env.reset(seed=seed)
        while True:
            o, r, te, tr, info = env.step(pol(o))
            if te or tr: break
        out.append(info["release_speed"] / info["rigid_speed"] if info["released"] and info["release_speed"] > 0 else 0.0)
    return np.array(out)
what = sys.argv[1]; res = {}
if what == "stiffness":
    env = gym.make("VSWrist/Throw-v0")
    for c in np.linspace(-1, 1, 9):
        res[f"c{c:+.2f}"] = ratios(env, lambda e, c=c: constant_policy(e, c))
    for lo in (-1.0, -0.75, -0.5, -0.25, 0.0):
        for hi in (-0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0):
            if hi > lo:
                res[f"r{lo:+.2f},{hi:+.2f}"] = ratios(env, lambda e, lo=lo, hi=hi: within(adaptive_policy(e), (lo, hi)))
else:
    s0 = float(sys.argv[2])
    env = gym.make("VSWrist/Throw-v0", config={"action_mode": "residual", "residual": {"posture_scale": 0.15, "stiffness_scale": 0.0, "stiffness_nominal": s0}})
    for lv in itertools.product((-1.0, -0.5, 0.0, 0.5, 1.0), repeat=3):
        res["t" + ",".join(f"{v:+.1f}" for v in lv)] = ratios(env, lambda e, lv=lv: trim_policy(e, lv))
    what = f"trims{s0:+.1f}"
np.savez_compressed(f"ratios_{what}.npz", seeds=np.array(SEEDS), **res)
for k, v in res.items():
    print(f"{k}: mean {v[:40].mean():.3f} sd {v[:40].std():.3f}")
