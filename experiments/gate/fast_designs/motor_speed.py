"""Fast Impact design: the PM motors' largest speed and the free episodes' largest FE error at three constants.
Probe episodes (reset seeds 1000-1009)."""
import numpy as np, gymnasium as gym, vswrist_gym, json, sys
from vswrist_gym.tools.probe import constant_policy
task = json.loads(sys.argv[1])
for s in (-1.0, 0.0, 1.0):
    mx = []; lag = []
    for seed in range(1000, 1010):
        env = gym.make("VSWrist/Impact-v1", config={"task": task}); u = env.unwrapped; pol = constant_policy(env, s)
        o, _ = env.reset(seed=seed); prev = o[u.obs_slices["motor_angles"]].copy(); m = 0; L = 0
        while True:
            o, r, te, tr, info = env.step(pol(o)); ma = o[u.obs_slices["motor_angles"]]
            m = max(m, np.abs((ma - prev)[:3]).max() / u.ctrl_dt); prev = ma.copy()
            L = max(L, abs(o[u.obs_slices["posture"]][1] - o[u.obs_slices["target"]][1]) if not u._obstacle else 0)
            if te or tr: break
        mx.append(m); lag.append(L)
    print(f"s={s:+.1f}: max PM motor speed {np.mean(mx):.2f} rad/s (limit {u.nominal_params.motor.speed_limit}), max FE error in free episodes {np.mean([l for l in lag if l>0] or [0]):.3f} rad")
