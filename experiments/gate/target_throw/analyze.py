"""Target-speed throw, offline: from the per-episode release ratios (collect.py), the reward of each agent when
each episode draws a target ratio r* ~ U[lo, hi] (observed). Agents: the best of the five gate constants (chosen on
training seeds 100-139); the rule: a lookup from r* to the stiffness schedule (a constant or Throw's soft/stiff rule
at some levels) whose training reward at r* is highest; the best open-loop posture trim per target at the constant
(the same lookup over 125 trims). Measured on probe episodes 1000-1059, paired.
Usage: analyze.py lo hi reward(l1|tentTAU) [trim files...]"""
import sys, numpy as np
lo, hi, kind = float(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
S = dict(np.load("ratios_stiffness.npz")); seeds = S.pop("seeds"); tr, pr = seeds < 1000, seeds >= 1000
T = {}
for f in sys.argv[4:]:
    d = dict(np.load(f)); d.pop("seeds"); T[f] = d
def rew(r, t):
    e = np.abs(r - t)
    return -e if kind == "l1" else np.maximum(0.0, 1.0 - e / float(kind[4:]))
rng = np.random.default_rng(0)
grid = np.linspace(lo, hi, 45)
tgt = rng.uniform(lo, hi, seeds.size)  # one target per episode
def lookup(family):
    """Per target on the grid, the agent of ``family`` with the highest mean training reward; applied on probe
    episodes with their targets (nearest grid point)."""
    names = list(family); R = np.stack([family[n] for n in names])  # (agents, episodes)
    best = [names[int(np.argmax([rew(R[i, tr], g).mean() for i in range(len(names))]))] for g in grid]
    idx = np.abs(tgt[:, None] - grid[None]).argmin(1)
    return np.array([rew(family[best[idx[e]]][e], tgt[e]) for e in range(seeds.size)]), best
consts = {k: S[k] for k in ("c-1.00", "c-0.50", "c+0.00", "c+0.50", "c+1.00")}
cm = {k: rew(v[tr], tgt[tr]).mean() for k, v in consts.items()}
bc = max(cm, key=cm.get)
base = rew(S[bc], tgt)
rule, chosen = lookup(S)
n = pr.sum()
def pair(x):
    d = (x - base)[pr]; return d.mean(), d.std(ddof=1) / np.sqrt(n)
h, se = pair(rule)
print(f"targets U[{lo},{hi}] reward {kind}: constants (training) " + " ".join(f"{k}:{v:+.3f}" for k, v in cm.items()))
print(f"  best constant {bc}: probe mean {base[pr].mean():+.3f}; rule {rule[pr].mean():+.3f}; headroom {h:+.3f} (se {se:.3f}, z {h/se:.1f})")
print("  rule's choices over the grid:", " ".join(sorted(set(chosen), key=chosen.index)))
for f, fam in T.items():
    s0 = f.split("trims")[1][:-4]
    if abs(float(s0) - float(bc[1:])) > 1e-6: continue
    trim, ch = lookup(fam)
    g, gse = pair(trim)
    print(f"  posture trims at s={s0} by target: gain {g:+.3f} (se {gse:.3f}), share {g/h:.2f}")
