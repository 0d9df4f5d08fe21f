import sys, numpy as np, gymnasium as gym
sys.path.insert(0, __import__("os").path.dirname(__file__))
import vswrist_gym
from target_env import register_probe
from vswrist_gym.tools.probe import constant_policy
eid = register_probe()
env = gym.make(eid); u = env.unwrapped
for s in (0.0, 1.0):
    for seed in (100, 1000):
        pol = constant_policy(env, s); o, _ = env.reset(seed=seed); R = 0
        while True:
            o, r, te, tr, info = env.step(pol(o)); R += r
            if te or tr: break
        print(s, seed, round(info["release_speed"] / info["rigid_speed"], 3), round(info["target_ratio"], 3), round(R, 2), info["is_success"], o[u.obs_slices["target_speed"]])
v = gym.make_vec(eid, num_envs=4, vectorization_mode="vector_entry_point"); o, _ = v.reset(seed=100); print(o.shape)
