"""Task variants on the literal ``paper`` springs, with the task's loads scaled to that device.

The tasks are sized for ``paper_knm`` (K = 4 N m): loads of newtons and tenths of N m against a coupler stiffness of
9.4-27 N m/rad at home. The literal ``paper`` springs (K = 4 N mm) give 0.0094-3.0 N m/rad there, a far wider
ratio (about 300x against 2.8x), but they cannot hold those loads. A variant keeps each task's geometry, motions
and timing and scales every load to what the device provides:

* forces and torques (task loads, contact-force targets and bounds, ``scales.force``, the force/torque sensor's
  noise, the uncompensated tool's mass through ``randomize.tool_mass``) by ``force_scale``: the ratio of the two
  presets' stiffest coupler stiffness at home (the stiffness command s = +1, i.e. ``lam_max`` as the environments
  compute it). A load then deflects the stiffest ``paper`` wrist exactly as much as the same task's load deflects
  the stiffest ``paper_knm`` wrist; only the soft end of the range differs;
* elastic energies (``scales.energy``, success bounds on the mean elastic energy) by ``energy_scale``: the ratio of
  the energies the springs store at that stiffest command, so that holding full stiffness costs the same share of
  the reward and of the success bound in both presets.

Angles, times, lengths and friction coefficients are left as they are. The hand (0.3 kg, a device parameter, not
a task load) is not scaled; the controller's gravity compensation holds its weight at the reference posture.
Hammer has no variant: with the hand unscaled the soft springs cannot swing it in time (docs/environments.md).

``python -m vswrist_gym.envs.variants --write`` writes ``configs/envs/variants/<preset>_<task>.yaml`` (the
overrides for ``gymnasium.make(id, config=...)``, read back with :func:`variant_config`); ``--check`` fails if
they are stale (the test suite runs it).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np
import yaml

from .config import ENV_CONFIG_DIR, EnvConfigError, load_env_config

VARIANT_DIR = ENV_CONFIG_DIR / "variants"
REFERENCE = "paper_knm"  # the preset the tasks are sized for (defaults.yaml's `params`)
VARIANT_PRESETS = ("paper",)

# Per task (config stem): the settings that are forces or torques (or a load mass, whose weight is a force) and
# those that are elastic energies. Common ones apply to every task.
FORCE_KEYS_COMMON = ("scales.force", "randomize.sensor_noise.force", "randomize.sensor_noise.torque",
                     "randomize.tool_mass.range")
ENERGY_KEYS_COMMON = ("scales.energy",)
FORCE_KEYS = {
    "load_hold": ("task.load_mass",),
    "polish": ("task.force_target", "task.force_tolerance"),
    "impact": ("task.success_force",),
    "insertion": ("task.fit_force", "task.success_wall_force"),
    "drill": ("task.torque_amplitude", "task.axial_force"),
}
ENERGY_KEYS = {
    "load_hold": ("task.success_energy",),
    "insertion": ("task.success_energy",),
    "drill": ("task.success_energy",),
}
# The best constant stiffness command of each variant, measured (python -m vswrist_gym.tools.probe --variant paper
# --episodes 12, docs/environments.md "Stiffness range"): the residual mode's zero action is that baseline.
BEST_CONSTANT = {"paper": {"load_hold": 1.0, "polish": 0.5, "impact": 1.0, "insertion": 0.5, "drill": 0.0}}
DIGITS = 4  # significant digits written to the YAML files


def stem(task: str) -> str:
    """Config stem of a task's short name: 'LoadHold' -> 'load_hold' (a stem passes through)."""
    return re.sub(r"(?<!^)(?=[A-Z])", "_", task).lower()


def stiffest(params) -> tuple[float, float]:
    """(coupler stiffness, N m/rad; elastic energy, J) at home at the environments' stiffest command, lam_max:
    the largest internal torque reachable at every posture of the range of motion (``envs.actions``), on the
    complete static stiffness (load term included; isotropic at home, so the mean of the diagonal)."""
    from ..control import AnalyticController
    from ..kinematics import WristKinematics
    from ..params import load_params
    from ..stiffness import coupler_stiffness, spring_energy, spring_deflection

    p = load_params(params)
    ctrl = AnalyticController(params=p)
    rom = p.range_of_motion
    lam_max = min(ctrl.lambda_range(np.array([a, b]))[1]
                  for a in np.linspace(rom.rud_min, rom.rud_max, 5) for b in np.linspace(rom.fe_min, rom.fe_max, 5))
    home = np.zeros(2)
    tau = lam_max * WristKinematics(p).internal_torque_basis(home)
    energy = float(np.sum(spring_energy(spring_deflection(tau, p), p)))
    return float(np.trace(coupler_stiffness(home, lam_max, p))) / 2.0, energy


def scales(params: str, reference: str = REFERENCE) -> tuple[float, float]:
    """(force_scale, energy_scale) of ``params`` against ``reference`` (module docstring)."""
    (s1, e1), (s0, e0) = stiffest(params), stiffest(reference)
    return s1 / s0, e1 / e0


def _round(x: float) -> float:
    return float(f"{x:.{DIGITS}g}")


def _scaled(value, factor: float):
    if isinstance(value, (list, tuple)):
        return [_round(v * factor) for v in value]
    return _round(value * factor)


def scaled_overrides(task: str, params: str = "paper") -> dict:
    """The ``config`` overrides of ``task`` on device preset ``params``: every force/torque setting of the task's
    configuration times the force scale, every energy setting times the energy scale (module docstring)."""
    s = stem(task)
    if s not in FORCE_KEYS:
        raise EnvConfigError(f"no '{params}' variant of task '{task}'; variants exist for {sorted(FORCE_KEYS)}")
    if params not in VARIANT_PRESETS:
        raise EnvConfigError(f"no variant preset '{params}'; choose one of {list(VARIANT_PRESETS)}")
    cfg = load_env_config(s)
    fs, es = scales(params)
    out: dict = {"params": params}
    for keys, factor in ((FORCE_KEYS_COMMON + FORCE_KEYS[s], fs), (ENERGY_KEYS_COMMON + ENERGY_KEYS.get(s, ()), es)):
        for dotted in keys:
            *path, leaf = dotted.split(".")
            src, dst = cfg, out
            for k in path:
                src, dst = src[k], dst.setdefault(k, {})
            dst[leaf] = _scaled(src[leaf], factor)
    if s in BEST_CONSTANT.get(params, {}):
        out["residual"] = {"stiffness_nominal": BEST_CONSTANT[params][s]}
    return out


def variant_path(task: str, params: str = "paper") -> Path:
    return VARIANT_DIR / f"{params}_{stem(task)}.yaml"


def variant_config(task: str, params: str = "paper") -> dict:
    """The committed overrides of ``task``'s ``params`` variant, for ``gymnasium.make(id, config=...)``."""
    path = variant_path(task, params)
    if not path.is_file():
        raise EnvConfigError(f"no '{params}' variant of task '{task}' ({path} does not exist); variants exist for "
                             f"{sorted(FORCE_KEYS)}")
    return yaml.safe_load(path.read_text())


def render(task: str, params: str = "paper") -> str:
    fs, es = scales(params)
    head = (f"# VSWrist/{task}: the '{params}' variant (generated: python -m vswrist_gym.envs.variants --write;\n"
            f"# the rule is in vswrist_gym/envs/variants.py). Loads scaled to the device: forces and torques x "
            f"{fs:.4g}\n# (ratio of the stiffest coupler stiffness at home, {params} / {REFERENCE}), elastic "
            f"energies x {es:.4g}\n# (ratio of the energy stored at that stiffness). Use: gym.make(id, "
            f"config=vswrist_gym.envs.variants.variant_config('{task}')).\n")
    return head + yaml.safe_dump(scaled_overrides(task, params), sort_keys=False, default_flow_style=None)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--write", action="store_true", help="write configs/envs/variants/<preset>_<task>.yaml")
    g.add_argument("--check", action="store_true", help="fail if a committed variant file is stale")
    g.add_argument("--print", action="store_true", help="print the force and energy scales and the overrides")
    args = ap.parse_args(argv)
    from .. import TASKS
    stale = []
    for params in VARIANT_PRESETS:
        if args.print:
            fs, es = scales(params)
            print(f"{params} against {REFERENCE}: force scale {fs:.4f}, energy scale {es:.4f}")
        for task in TASKS:
            if stem(task) not in FORCE_KEYS:
                continue
            text, path = render(task, params), variant_path(task, params)
            if args.write:
                path.parent.mkdir(parents=True, exist_ok=True)
                path.write_text(text)
                print(f"{path}")
            elif args.check and (not path.is_file() or path.read_text() != text):
                stale.append(str(path))
            elif args.print:
                print(text)
    if stale:
        print("stale (run python -m vswrist_gym.envs.variants --write): " + ", ".join(stale), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
