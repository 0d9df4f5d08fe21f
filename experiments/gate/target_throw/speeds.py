"""Target-speed throw, first numbers: the release speed (x the rigid bound) that each constant stiffness and a few
open-loop posture trims reach on Throw-v0's counter-movement. Probe episodes (reset seeds 1000-...)."""
import sys, time, numpy as np, gymnasium as gym
import vswrist_gym
from vswrist_gym.tools.probe import constant_policy, adaptive_policy, within, trim_policy
N = int(sys.argv[1]) if len(sys.argv) > 1 else 6
def ratios(fac, mode=None, s0=0.0):
    cfg = {} if mode is None else {"action_mode": "residual", "residual": {"posture_scale": 0.15, "stiffness_scale": 0.0, "stiffness_nominal": s0}}
    env = gym.make("VSWrist/Throw-v0", config=cfg); out = []
    for i in range(N):
        pol = fac(env); o, _ = env.reset(seed=1000 + i)
        while True:
            o, r, te, tr, info = env.step(pol(o))
            if te or tr: break
        out.append(info["release_speed"] / info["rigid_speed"] if info["released"] else np.nan)
    return np.array(out)
t = time.time()
for s in (-1, -0.5, 0, 0.5, 1):
    print(f"s={s:+.1f}: {np.round(ratios(lambda e, s=s: constant_policy(e, s)), 2)}", flush=True)
print(f"rule(-1,+1): {np.round(ratios(adaptive_policy), 2)}")
print(f"rule(-1,+0.5): {np.round(ratios(lambda e: within(adaptive_policy(e), (-1, 0.5))), 2)}")
print(f"rule(-1,0): {np.round(ratios(lambda e: within(adaptive_policy(e), (-1, 0))), 2)}")
print(f"rule(-0.5,+1): {np.round(ratios(lambda e: within(adaptive_policy(e), (-0.5, 1))), 2)}")
for s0 in (0.0, 0.5):
    for lv in ((-1, 0, 0), (1, 0, 0), (1, 1, 1), (-1, -1, -1), (0, 1, 1), (0, -1, -1), (1, -1, -1), (-1, 1, 1)):
        print(f"s0={s0:+.1f} trim {lv}: {np.round(ratios(lambda e, lv=lv: trim_policy(e, lv), 'res', s0), 2)}", flush=True)
print(f"{time.time()-t:.0f} s")
