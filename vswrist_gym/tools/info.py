"""``vswrist info``: the device parameters, the stiffness range at home, and a kinematics self-check."""

from __future__ import annotations

import argparse
import dataclasses
import sys

import numpy as np

from ..kinematics import WristKinematics
from ..params import PRESETS, ParamsError, load_params
from ..stiffness import coupler_stiffness, lambda_range, max_leg_torque


def env_preset() -> str:
    """The device preset the environments are built on: the `params` of their shared defaults.yaml."""
    from ..envs.config import ENV_CONFIG_DIR, _read

    return str(_read(ENV_CONFIG_DIR / "defaults.yaml")["params"])


def self_check(kin: WristKinematics, samples: int = 500, seed: int = 0) -> float:
    """Largest |FK(IK(T)) - T| over random postures in the range of motion and all three legs."""
    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(samples):
        T = kin.coupler_pose(rng.uniform(kin.u_min, kin.u_max))
        for leg in range(3):
            worst = max(worst, float(np.abs(kin.leg_forward(kin.leg_inverse(T, leg), leg) - T).max()))
    return worst


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="vswrist info", description=__doc__)
    env_params = env_preset()
    parser.add_argument("--params", default=None,
                        help=f"preset ({', '.join(PRESETS)}) or YAML file; default: the environments' preset "
                             f"({env_params})")
    args = parser.parse_args(argv)
    source = env_params if args.params is None else args.params
    try:
        params = load_params(source)
    except ParamsError as exc:
        print(f"vswrist info: error: --params: {exc}", file=sys.stderr)
        return 2
    kin = WristKinematics(params)
    whose = " (the environments' preset)" if params.name == env_params else \
        f" (the environments use {env_params})"
    print(f"VS-Wrist parameter preset: {params.name}{whose}")
    for section in dataclasses.fields(params):
        if section.name == "name":
            continue
        values = getattr(params, section.name)
        print(f"  {section.name}:")
        for f in dataclasses.fields(values):
            print(f"    {f.name:<18} {getattr(values, f.name)!s:<40} {params.unit(section.name, f.name)}")
    u0 = np.zeros(2)
    lo, hi = lambda_range(u0, params)
    soft = coupler_stiffness(u0, 0.0, params)
    stiff = coupler_stiffness(u0, hi, params)
    softest = coupler_stiffness(u0, lo, params)
    print("\nStiffness at home (u = 0), eigenvalues of Sigma_c in N m/rad:")
    print(f"  per-leg torque limit             {max_leg_torque(params):.4g} N m")
    print(f"  internal torque lambda range     [{lo:.4g}, {hi:.4g}] N m (positive stiffens)")
    print(f"  lambda = 0                       {np.linalg.eigvalsh(soft).round(5)}")
    print(f"  lambda = {hi:<8.4g}                {np.linalg.eigvalsh(stiff).round(5)}")
    print(f"  lambda = {lo:<8.4g}                {np.linalg.eigvalsh(softest).round(5)}")
    print(f"  stiffness ratio (max / zero)     {np.linalg.eigvalsh(stiff).max() / np.linalg.eigvalsh(soft).max():.1f}")
    err = self_check(kin)
    print(f"\nKinematics self-check: max |FK(IK(T)) - T| over 500 postures x 3 legs = {err:.2e}"
          f" ({'ok' if err < 1e-10 else 'FAILED'})")
    return 0 if err < 1e-10 else 1


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
