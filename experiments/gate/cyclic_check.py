"""Design check of two cyclic tasks, dropped before any gate run (probe seeds 1000-1003 only; NOTES.md).

Hammer-v1's wrist and hammer (head mass and handle drawn per episode), the anvil moved out of reach
(``fe_strike`` 0.9-0.92 rad), the posture reference replaced after reset by a cyclic FE motion; the stiffness
command held (constants) or switched by a rule; the score is the head's mean speed (m/s) from 0.3-0.4 s to the end,
read at the end of each control period.

1. *Speed-limited swing*: a triangle between -0.45 and +0.45 rad, the fastest motor at its speed limit (Hammer's
   ``_fe_rate``), 1.5 s. The rule: stiffness ``hi`` for ``tau`` s after each turn of the reference, ``lo`` else.
   The posture substitute: the best constant with a triangle 0.15 rad larger or smaller (what a posture residual
   of 0.15 rad can do: at the speed limit it changes the period and so retunes the drive to the spring).
2. *Commanded tempo*: a sine of 0.35 rad at a fixed frequency, 2 s; every constant at each frequency.

    python experiments/gate/cyclic_check.py > experiments/gate/cyclic_check.txt
"""

import numpy as np
import gymnasium as gym
import mujoco

import vswrist_gym  # noqa: F401
from vswrist_gym.envs.ramp import ramp_reference

CONSTANTS = (-1.0, -0.5, 0.0, 0.5, 1.0)


def play(seed, reference, stiffness, episode_s, settle_s):
    """Mean head speed (m/s) after ``settle_s`` of an episode whose FE reference is ``reference(u) -> (times, fe,
    turns)`` and whose stiffness command is ``stiffness(t, turns)``."""
    env = gym.make("VSWrist/Hammer-v1", config={"episode_s": episode_s, "action_mode": "posture_stiffness",
                                                "task": {"fe_strike": [0.9, 0.92], "fe_start": 0.0,
                                                         "fe_back": -0.01}})
    u = env.unwrapped
    env.reset(seed=seed)
    ts, fes, turns = reference(u)
    u._swing_t, u._swing_fe = ts, fes
    u._ep.references[0] = u._reference(np.arange(u.episode_steps + 1) * u.ctrl_dt)
    u._ep.target[0] = u._ep.references[0, 0]
    v6, speeds = np.zeros(6), []
    for k in range(u.episode_steps):
        a = u.reference_to_action(u._ep.target[0], stiffness(k * u.ctrl_dt, turns))
        _, _, te, tr, _ = env.step(a)
        mujoco.mj_objectVelocity(u.model, u.data, mujoco.mjtObj.mjOBJ_BODY, u._head_body, v6, 0)
        speeds.append(np.linalg.norm(v6[3:]))
        if te or tr:
            break
    env.close()
    return float(np.mean(speeds[int(round(settle_s / u.ctrl_dt)):]))


def triangle(lo, hi, t0=0.05):
    def reference(u):
        ts, fes, t, fe, turns = [0.0], [0.0], t0, 0.0, []
        target = lo
        while t <= u.cfg["episode_s"]:
            tt, ff = ramp_reference(fe, target, u._fe_rate, t, u.cfg["episode_s"] + 1.0)
            ts += list(tt[1:-1])
            fes += list(ff[1:-1])
            t, fe = float(tt[-2]), target
            turns.append(t)
            target = hi if target == lo else lo
        ts, fes = np.array(ts), np.array(fes)
        keep = np.concatenate([[True], np.diff(ts) > 0])
        return ts[keep], fes[keep], np.array(turns)
    return reference


def sine(freq, amp=0.35):
    def reference(u):
        ts = np.arange(0.0, u.cfg["episode_s"] + 0.1, 1e-3)
        return ts, amp * np.minimum(ts / 0.2, 1.0) * np.sin(2 * np.pi * freq * ts), np.zeros(0)
    return reference


def after_turn(tau, lo, hi):
    def stiffness(t, turns):
        past = turns[turns <= t]
        return hi if past.size and t - past[-1] < tau else lo
    return stiffness


def mean_sd(values):
    return f"{np.mean(values):.2f} ({np.std(values, ddof=1) / np.sqrt(len(values)):.2f})"


def main():
    seeds = range(1000, 1004)
    print("1. speed-limited swing, +-0.45 rad, 1.5 s; head's mean speed after 0.3 s, m/s (s.e.), seeds 1000-1003")
    swing = lambda stiff, lo=-0.45, hi=0.45: [play(s, triangle(lo, hi), stiff, 1.5, 0.3) for s in seeds]  # noqa
    for c in CONSTANTS:
        print(f"  constant {c:+.1f}: {mean_sd(swing(lambda t, turns, c=c: c))}")
    for tau in (0.02, 0.03):
        for lo, hi in ((-1.0, 1.0), (-1.0, 0.5), (-0.5, 1.0)):
            print(f"  rule: {hi:+.1f} for {tau:g} s after each turn, {lo:+.1f} else: "
                  f"{mean_sd(swing(after_turn(tau, lo, hi)))}")
    for d in (-0.15, 0.15):
        print(f"  constant +1.0, triangle {d:+.2f} rad larger: "
              f"{mean_sd(swing(lambda t, turns: 1.0, -0.45 - d, 0.45 + d))}")
    print("\n2. commanded tempo, sine of 0.35 rad, 2 s; head's mean speed after 0.4 s, m/s, seeds 1000-1002")
    print("  Hz   " + "  ".join(f"{c:+.1f}" for c in CONSTANTS))
    for f in (1.0, 1.5, 2.0, 2.5, 3.0, 3.5):
        row = [np.mean([play(s, sine(f), lambda t, turns, c=c: c, 2.0, 0.4) for s in range(1000, 1003)])
               for c in CONSTANTS]
        print(f"  {f:.1f}  " + "  ".join(f"{v:.2f}" for v in row))


if __name__ == "__main__":
    main()
