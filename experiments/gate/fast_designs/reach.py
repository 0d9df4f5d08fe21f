"""Feasibility: a fast reach-and-hold at the motors' speed limit after a counter-movement (Throw's wind-up):
does a stiffness schedule bring the link to the goal sooner than a constant, and can it settle? Probe seeds only."""
import sys, numpy as np, gymnasium as gym
import vswrist_gym
from vswrist_gym.tools.probe import constant_policy, adaptive_policy

cfg = {"episode_s": 1.2, "task": {"fe_release": [0.93, 0.94], "fe_end": 0.95, "ball_mass": [0.1, 0.3]}}
def run(pol_fac, seed):
    env = gym.make("VSWrist/Throw-v0", config=cfg); u = env.unwrapped
    pol = pol_fac(env); o, _ = env.reset(seed=seed); sl = u.obs_slices if hasattr(u, "obs_slices") else None
    fe, ref, t = [], [], []
    while True:
        a = pol(o); o, r, te, tr, info = env.step(a)
        fe.append(float(o[u.obs_slices["posture"]][1]))
        ref.append(float(u._reference(u._t)[1])); t.append(u._t)
        if te or tr: break
    return np.array(t), np.array(fe), np.array(ref), u
for name, fac in [(f"s={s:+.1f}", (lambda s: (lambda env: constant_policy(env, s)))(s)) for s in (-1, -0.5, 0, 0.5, 1)] + [("rule", adaptive_policy)]:
    arr, ov, rms = [], [], []
    for seed in range(1000, 1006):
        t, fe, ref, u = run(fac, seed)
        goal = 0.95
        hit = np.flatnonzero(fe >= goal - 0.02)
        ta = t[hit[0]] if hit.size else np.inf
        arr.append(ta - u._swing_t0); ov.append(fe.max() - goal)
        after = (t > ta) & (t < ta + 0.4)
        rms.append(np.sqrt(np.mean((fe[after] - goal) ** 2)) if after.any() else np.nan)
    print(f"{name:7s} arrival after swing start {np.mean(arr):.3f} s  overshoot {np.mean(ov):+.3f} rad  rms 0.4 s after {np.nanmean(rms):.3f}")
