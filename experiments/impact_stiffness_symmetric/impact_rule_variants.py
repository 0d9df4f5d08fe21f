"""Does Impact's rule need memory, or smoothness? The probe's rule (stiff in free motion, soft while a contact is
felt and for ``IMPACT_SOFT_S`` after it, the command slewed at ``SLEW`` per second) against variants, on the
probe's 12 held-out episodes (seeds 1000-1011), paired with the best constant (-1):

    python experiments/impact_stiffness_symmetric/impact_rule_variants.py

Variants: the hold after the last contact at 0.3 s (the rule), 0.1 s and 0.02 s (one control step: memoryless
but for the slew), and without the slew (the command jumps; hold 0.02 s and 0.3 s)."""
import numpy as np
import gymnasium as gym

import vswrist_gym  # noqa: F401
import vswrist_gym.tools.probe as P

env = gym.make("VSWrist/Impact-v0")
seeds = range(1000, 1012)
base: list = []
P.evaluate(env, lambda: P.constant_policy(env, -1.0), seeds, returns=base)
base = np.array(base)
print(f"best constant (-1): mean return {base.mean():.1f}")
defaults = (P.IMPACT_SOFT_S, P.SLEW)
for slew in (defaults[1], 1e9):
    for hold in (0.3, 0.1, 0.02):
        if slew > 1e6 and hold == 0.1:
            continue
        P.IMPACT_SOFT_S, P.SLEW = hold, slew
        out: list = []
        P.evaluate(env, lambda: P.adaptive_policy(env), seeds, returns=out)
        d = np.array(out) - base
        label = f"hold {hold:g} s, " + ("slew 4/s" if slew < 1e6 else "no slew")
        print(f"{label:<24} paired {d.mean():+6.1f} (s.e. {d.std(ddof=1) / np.sqrt(len(d)):.1f})")
P.IMPACT_SOFT_S, P.SLEW = defaults
