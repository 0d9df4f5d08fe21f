"""Diagnostic (not part of the gate): where does the reference agent's static posture error come from?

The reference agent (the analytic controller at a constant stiffness command, ``probe.constant_policy``) is run on
tuning episodes only (TUNING_EVAL_SEEDS[:2] x 10, the same episodes as ``trim_diagnostic.py``; no held-out episode
is read) at the constant command its gate selected (experiments/gate/<Task>-vN.json), and its posture error
(measured posture - reference, rad, per axis RUD, FE, PS) is averaged over the steps of free motion: before the
load (LoadHold), outside the drill's engagement (Drill), without contact (Impact, Insertion), and over the steps
where the reference stands still (reference speed < 0.01 rad/s on every axis) among those.

Each line is one physical cause removed at a time, so that the difference to the first line is that cause's
share of the error:

* ``as is``: the environment as registered;
* ``no tool weight``: the tool's mass set to 1 g (its inertia scaled alike): the uncompensated tool;
* ``no PS/legs weight``: the PS flange's and the legs' masses set to 1 g: what the controller's compensation
  ignores besides the tool;
* ``no gravity``: gravity off in the physics and in the controller's compensation: everything that is weight;
* ``no friction``: the leg and PS joints' viscous damping set to zero: friction (it matters in motion only);
* ``tool compensated``: ``compensate_tool: true`` (the controller also holds the PS flange and the tool at their
  nominal masses).

    PYTHONPATH=. python experiments/gate/sag_diagnostic.py [TASK_ID ...] [--variants as_is,no_tool,...]
"""

import argparse
import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401  (registers the ids)
from vswrist_gym.agents.protocol import TUNING_EVAL_SEEDS, reset_seed
from vswrist_gym.tools.probe import constant_policy

SEEDS, EPISODES = TUNING_EVAL_SEEDS[:2], 10
TINY = 1e-3  # kg: a mass "removed" (MuJoCo needs a positive mass on a moving body)
STILL = 0.01  # rad/s: the reference counts as standing still below this speed on every axis


def _free_mask(env, n):
    """Per step (1..n): whether the step is free motion (no task load, no contact)."""
    t = (np.arange(n) + 1) * env.ctrl_dt
    name = env.task
    if name == "load_hold":
        return t < env._onset
    if name == "drill":
        return (t <= env._t_on) | (t > env._t_off)
    contact = np.array(env._history["contact"])
    return contact <= 0.5


def _apply(env, variant):
    m = env.model
    if variant == "no_tool":
        if env._nominal_tool_mass <= TINY:
            return
        scale = TINY / env._nominal_tool_mass
        env._nominal_tool_mass = TINY
        env._nominal_tool_inertia = env._nominal_tool_inertia * scale
    elif variant == "no_ps_legs":
        for b in range(m.nbody):
            name = m.body(b).name
            if name == "ps" or "_link" in name:
                m.body_inertia[b] *= TINY / m.body_mass[b]
                m.body_mass[b] = TINY
    elif variant == "no_gravity":
        m.opt.gravity[:] = 0.0
        env.ctrl._gravity = (0.0, 0.0, 0.0)
    elif variant == "no_friction":
        m.dof_damping[:] = 0.0


def run(env_id, variant, constant):
    config = {"compensate_tool": True} if variant == "tool_comp" else {}
    env = gym.make(env_id, config=config)
    u = env.unwrapped
    _apply(u, variant)
    free_all, still_all, loaded_all, rets = [], [], [], []
    for s in SEEDS:
        for i in range(EPISODES):
            obs, _ = env.reset(seed=reset_seed(s, i))
            if variant in ("no_ps_legs", "no_gravity", "no_friction"):
                _apply(u, variant)  # a reset that rebuilds the model would undo it; the settle already ran
            pol = constant_policy(env, constant)
            done, ret = False, 0.0
            while not done:
                obs, r, term, trunc, info = env.step(pol(obs))
                ret += r
                done = term or trunc
            err = np.array(u._history["error"])
            speed = np.abs(np.gradient(u._references[:len(err) + 1], u.ctrl_dt, axis=0))[1:]
            free = _free_mask(u, len(err))
            still = free & np.all(speed < STILL, axis=1)
            loaded_all.append(err[~free])
            free_all.append(err[free])
            still_all.append(err[still])
            rets.append(ret)
    env.close()
    f, st, ld = np.concatenate(free_all), np.concatenate(still_all), np.concatenate(loaded_all)
    return (f.mean(axis=0), st.mean(axis=0) if len(st) else np.full(3, np.nan), len(st), float(np.mean(rets)),
            ld.mean(axis=0) if len(ld) else np.full(3, np.nan))


VARIANTS = {"as_is": "as is", "no_tool": "no tool weight", "no_ps_legs": "no PS/legs weight",
            "no_gravity": "no gravity", "no_friction": "no friction", "tool_comp": "tool compensated"}


def main(argv):
    ap = argparse.ArgumentParser()
    ap.add_argument("ids", nargs="*", default=["VSWrist/LoadHold-v1", "VSWrist/Impact-v0", "VSWrist/Drill-v1",
                                                 "VSWrist/Insertion-v0"])
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--constant", type=float, default=None, help="default: the gate's selected constant")
    args = ap.parse_args(argv)
    for env_id in args.ids:
        if args.constant is None:
            path = Path("experiments/gate") / f"{env_id.split('/')[-1]}.json"
            c = json.loads(path.read_text())["selection"]["best_constant"]
        else:
            c = args.constant
        for v in args.variants.split(","):
            free, still, n_still, ret, loaded = run(env_id, v, c)
            print(f"{env_id} s = {c:+.1f} {VARIANTS[v]:>18}: mean error free (RUD, FE, PS) "
                  f"{np.round(free, 4).tolist()} rad; reference still ({n_still} steps) "
                  f"{np.round(still, 4).tolist()} rad; loaded/contact {np.round(loaded, 4).tolist()} rad; "
                  f"mean return {ret:.1f}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
