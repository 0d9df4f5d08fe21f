"""A batch's one-thread CPU time and its ratio to the physics, on this code against another checkout, in
alternating processes (the VM's drift falls on both alike).

    python experiments/batched_speed/batch_ab_cpu.py OLD_CHECKOUT TASK [TASK ...]

Per task, five pairs of processes (old, new), each pinned to CPU 1: a batch of 32 worlds (one thread) steps 30
times to warm up, then 300 steps of random actions from a fixed generator; printed are the median over the
pairs of old / new CPU time, and each side's median of CPU time over the time inside the worlds' ``mj_step``
substeps of the compiled advance (``physics_seconds``: the resets' settling is not in it, so these ratios are
higher than ``vswrist bench-env``'s env/phys). Run it from outside the checkouts so that PYTHONPATH decides
which one is imported (``cd /tmp``)."""
import subprocess, sys, os, statistics, json
RUN = r'''
import sys, time, os, json
os.sched_setaffinity(0, {1})
import gymnasium as gym, numpy as np, vswrist_gym
from vswrist_gym import LATEST
eid = LATEST[sys.argv[1]]
v = gym.make_vec(eid, num_envs=32, vectorization_mode="vector_entry_point", threads=1)
v.reset(seed=0); rng = np.random.default_rng(0)
A = [rng.uniform(-1, 1, v.action_space.shape) for _ in range(330)]
for a in A[:30]: v.step(a)
v.unwrapped.physics_seconds = 0.0
t0 = time.process_time()
for a in A[30:]: v.step(a)
cpu = time.process_time() - t0
print(json.dumps([cpu, v.unwrapped.physics_seconds]))
'''
old, tasks = sys.argv[1], sys.argv[2:]
for task in tasks:
    res = {"old": [], "new": []}
    for k in range(5):
        for side in ("old", "new"):
            env = dict(os.environ)
            if side == "old": env["PYTHONPATH"] = old
            out = subprocess.run([sys.executable, "-c", RUN, task], env=env, capture_output=True, text=True, cwd="/tmp")
            res[side].append(json.loads(out.stdout.strip().splitlines()[-1]))
    o = [c for c, p in res["old"]]; n = [c for c, p in res["new"]]
    ro = [c / p for c, p in res["old"]]; rn = [c / p for c, p in res["new"]]
    print(f"{task:10s} old/new cpu {statistics.median([a/b for a, b in zip(o, n)]):.3f}  "
          f"cpu/phys-in-advance old {statistics.median(ro):.3f} new {statistics.median(rn):.3f}", flush=True)
