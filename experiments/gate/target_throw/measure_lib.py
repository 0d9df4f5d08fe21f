"""Shared pieces of the target-speed throw's probe scripts: episode returns on the probe id, paired differences, and
the target rule and trim lookups fitted on training seeds 100-139 from collect.py's ratios."""
import os, numpy as np, gymnasium as gym
from vswrist_gym.tools.probe import constant_policy, adaptive_policy, within, trim_policy  # noqa: F401

HERE = os.path.dirname(os.path.abspath(__file__))
TRAIN = list(range(100, 140))


def returns(eid, factory, seeds, kwargs=None, sb3=False):
    """Episode returns; ``factory(env, target)`` builds the agent once the reset has drawn the target."""
    env = gym.make(eid, **(kwargs or {})); u = env.unwrapped; out = []
    for seed in seeds:
        o, _ = env.reset(seed=seed); ag = factory(env, float(o[u.obs_slices["target_speed"]][0])); R = 0.0; first = True
        while True:
            a = ag.predict(o, episode_start=np.array([first]), deterministic=True)[0] if sb3 else ag(o); first = False
            o, r, te, tr, info = env.step(a); R += r
            if te or tr: break
        out.append(R)
    env.close()
    return np.array(out)


def paired(x, base):
    d = np.asarray(x) - np.asarray(base); return d.mean(), d.std(ddof=1) / np.sqrt(d.size)


def fit(path, lo, hi, tol, tr_seeds=TRAIN):
    """Target grid (41 points over [lo, hi]) -> the family member (a key of ``path``) with the highest mean training
    tent score at that target; returns (grid, names)."""
    grid = np.linspace(lo, hi, 41)
    d = dict(np.load(os.path.join(HERE, path))); seeds = list(d.pop("seeds")); idx = [seeds.index(s) for s in tr_seeds]
    names = list(d); R = np.stack([d[n][idx] for n in names])
    return grid, [names[int(np.argmax(np.maximum(0, 1 - np.abs(R - g) / tol).mean(1)))] for g in grid]


def pick(table, target):
    grid, names = table
    return names[int(np.abs(grid - target).argmin())]


def rule_factory(lo, hi, tol):
    """The target rule: from the observed target, a constant or Throw's rule (soft through the wind-up, stiff from
    the turn) at the levels whose training ratios come nearest it (``fit``)."""
    table = fit("ratios_stiffness.npz", lo, hi, tol)

    def make(env, target):
        k = pick(table, target)
        if k.startswith("c"):
            return constant_policy(env, float(k[1:]))
        a, b = map(float, k[1:].split(","))
        return within(adaptive_policy(env), (a, b))
    make.table = table
    return make


def trim_factory(s0, lo, hi, tol):
    """The best open-loop 3-segment FE trim (probe.trim_policy) per target at the constant s0 (``fit``)."""
    table = fit(f"ratios_trims{s0:+.1f}.npz", lo, hi, tol)
    return lambda env, target: trim_policy(env, tuple(float(v) for v in pick(table, target)[1:].split(",")))
