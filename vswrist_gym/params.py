"""Typed, frozen parameter sets of the VS-Wrist, loaded from YAML presets.

This module is the single source of truth for every physical constant: the analytic model, the MuJoCo
model, the simulator and the controller all read a :class:`WristParams`. Each YAML entry carries its
value, its unit (checked here, so a file written in other units fails loudly) and a reason.

Presets live in ``vswrist_gym/configs`` (``configs/`` at the repository root points there):
``paper`` (the default, K = 0.004 N m) and ``paper_knm`` (K = 4 N m). A preset may name a ``base``
preset and override only some entries.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import yaml

CONFIG_DIR = Path(__file__).resolve().parent / "configs"
DEFAULT_PRESET = "paper"
DEVICE_PRESETS = ("paper", "paper_knm")  # the two readings of the paper's spring constant (domain notes)
# `paper` with the motor dynamics identified from the paper's section-5 numbers (vswrist_gym.identify)
IDENTIFIED_PRESETS = ("paper_identified",)
# each device preset also with a 0.25 ms physics step: loop closure 17x below 1e-4 in commanded motion, at 4x
# the physics cost
PRESETS = DEVICE_PRESETS + ("paper_fine", "paper_knm_fine") + IDENTIFIED_PRESETS


class ParamsError(ValueError):
    """A parameter file is missing, malformed, or holds an impossible value."""


def _p(unit: str, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
       length: int | None = None) -> Any:
    """A dataclass field with its unit and allowed range (inclusive unless ``lo_open``)."""
    return field(metadata={"unit": unit, "lo": lo, "hi": hi, "lo_open": lo_open, "length": length})


@dataclass(frozen=True)
class Geometry:
    """Denavit-Hartenberg constants of the parallel mechanism (paper Table 1)."""

    d: float = _p("m", 0.0, lo_open=True)
    alpha: float = _p("rad", 0.0, math.pi, lo_open=True)
    eta: tuple[float, float, float] = _p("rad", -2 * math.pi, 2 * math.pi, length=3)


@dataclass(frozen=True)
class RangeOfMotion:
    """Posture limits of the real device: u = (alpha_y = RUD, alpha_z = FE) and the PS angle."""

    rud_min: float = _p("rad", -math.pi / 2, math.pi / 2)
    rud_max: float = _p("rad", -math.pi / 2, math.pi / 2)
    fe_min: float = _p("rad", -math.pi / 2, math.pi / 2)
    fe_max: float = _p("rad", -math.pi / 2, math.pi / 2)
    ps_min: float = _p("rad", -math.pi, math.pi)
    ps_max: float = _p("rad", -math.pi, math.pi)


@dataclass(frozen=True)
class Spring:
    """Non-linear spring tau = -2 K sinh(delta / delta0) between each PM motor and its leg."""

    K: float = _p("N*m", 0.0, lo_open=True)
    delta0: float = _p("rad", 0.0, lo_open=True)
    deflection_limit: float = _p("rad", 0.0, math.pi, lo_open=True)


@dataclass(frozen=True)
class Motor:
    """Position-controlled motors: low-pass reference, P(D) loop, torque and speed limits."""

    torque_limit: float = _p("N*m", 0.0, lo_open=True)
    speed_limit: float = _p("rad/s", 0.0, lo_open=True)
    time_constant: float = _p("s", 0.0, lo_open=True)
    kp: float = _p("N*m/rad", 0.0, lo_open=True)
    kd: float = _p("N*m*s/rad", 0.0)
    rotor_inertia: float = _p("kg*m^2", 0.0, lo_open=True)
    ps_torque_limit: float = _p("N*m", 0.0, lo_open=True)


@dataclass(frozen=True)
class Inertia:
    """Masses and inertias of the moving parts (estimates; reasons in the preset file)."""

    hand_mass: float = _p("kg", 0.0)
    hand_offset: float = _p("m", 0.0)
    link_mass: tuple[float, float, float] = _p("kg", 0.0, lo_open=True, length=3)
    link_inertia: tuple[float, float, float] = _p("kg*m^2", 0.0, lo_open=True, length=3)
    coupler_mass: float = _p("kg", 0.0, lo_open=True)
    coupler_inertia: float = _p("kg*m^2", 0.0, lo_open=True)
    ps_mass: float = _p("kg", 0.0, lo_open=True)
    ps_inertia: float = _p("kg*m^2", 0.0, lo_open=True)


@dataclass(frozen=True)
class Damping:
    """Linear viscous friction (the paper's D)."""

    leg_joint: float = _p("N*m*s/rad", 0.0)
    ps_joint: float = _p("N*m*s/rad", 0.0)


@dataclass(frozen=True)
class Environment:
    """Where the device is: the gravity vector in the base frame (X_b along the forearm)."""

    gravity: tuple[float, float, float] = _p("m/s^2", -100.0, 100.0, length=3)


@dataclass(frozen=True)
class Control:
    """Gains of the paper's stiffness optimiser (Levenberg-Marquardt dynamics on lambda)."""

    lm_alpha: float = _p("1/s", 0.0, lo_open=True)
    lm_nu: float = _p("-", 0.0, lo_open=True)


@dataclass(frozen=True)
class Simulation:
    """Numerical settings of the MuJoCo model: physics timestep and the loop-closure constraints.

    The three legs are closed onto the coupler by weld constraints; the internal preload (N m per leg)
    must not pull them apart, so the constraints are made nearly hard (impedance close to 1) with a
    short time constant. See docs/model.md for the accuracy/speed trade behind the defaults.
    """

    timestep: float = _p("s", 0.0, 0.01, lo_open=True)
    constraint_timeconst: float = _p("s", 0.0, 1.0, lo_open=True)
    constraint_dampratio: float = _p("-", 0.0, 10.0, lo_open=True)
    constraint_dmin: float = _p("-", 0.0, 1.0, lo_open=True)
    constraint_dmax: float = _p("-", 0.0, 1.0, lo_open=True)
    constraint_width: float = _p("m", 0.0, lo_open=True)
    stop_timeconst: float = _p("s", 0.0, 1.0, lo_open=True)
    solver_iterations: float = _p("-", 1.0, 1000.0)
    solver_tolerance: float = _p("-", 0.0, 1.0)


@dataclass(frozen=True)
class WristParams:
    """The complete parameter set of one VS-Wrist."""

    name: str
    geometry: Geometry
    range_of_motion: RangeOfMotion
    spring: Spring
    motor: Motor
    inertia: Inertia
    damping: Damping
    environment: Environment
    control: Control
    simulation: Simulation

    def replace(self, **sections: Mapping[str, Any]) -> "WristParams":
        """A copy with some entries changed, validated like a file: ``p.replace(spring={"K": 0.01})``."""
        raw = {s: {k: getattr(getattr(self, s), k) for k in _field_names(_SECTIONS[s])} for s in _SECTIONS}
        for section, values in sections.items():
            if section not in _SECTIONS:
                raise ParamsError(f"unknown parameter section '{section}'; allowed: {sorted(_SECTIONS)}")
            for key, value in values.items():
                if key not in raw[section]:
                    raise ParamsError(f"unknown parameter '{section}.{key}'; allowed: "
                                      f"{sorted(raw[section])}")
                raw[section][key] = value
        return _build(self.name + "*", raw, units=None)

    def unit(self, section: str, key: str) -> str:
        """The SI unit of one entry, as declared here."""
        return _meta(_SECTIONS[section], key)["unit"]


_SECTIONS: dict[str, type] = {
    "geometry": Geometry,
    "range_of_motion": RangeOfMotion,
    "spring": Spring,
    "motor": Motor,
    "inertia": Inertia,
    "damping": Damping,
    "environment": Environment,
    "control": Control,
    "simulation": Simulation,
}


def _field_names(cls: type) -> list[str]:
    return [f.name for f in dataclasses.fields(cls)]


def _meta(cls: type, key: str) -> Mapping[str, Any]:
    return {f.name: f.metadata for f in dataclasses.fields(cls)}[key]


def _range_text(meta: Mapping[str, Any]) -> str:
    lo, hi = meta["lo"], meta["hi"]
    left = "(" if meta["lo_open"] else "["
    lo_s = "-inf" if lo is None else f"{lo:g}"
    hi_s = "inf" if hi is None else f"{hi:g}"
    return f"{left}{lo_s}, {hi_s}]".replace(", inf]", ", inf)") + f" {meta['unit']}"


def _check_number(where: str, value: Any, meta: Mapping[str, Any]) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParamsError(f"'{where}' must be a number in {_range_text(meta)}, got {value!r} "
                          f"({type(value).__name__})")
    value = float(value)
    lo, hi = meta["lo"], meta["hi"]
    bad = (not math.isfinite(value)
           or (lo is not None and (value <= lo if meta["lo_open"] else value < lo))
           or (hi is not None and value > hi))
    if bad:
        raise ParamsError(f"'{where}' = {value:g} is outside the allowed range {_range_text(meta)}")
    return value


def _check_value(where: str, value: Any, meta: Mapping[str, Any]) -> Any:
    n = meta["length"]
    if n is None:
        return _check_number(where, value, meta)
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise ParamsError(f"'{where}' must be a list of {n} numbers in {_range_text(meta)}, got {value!r}")
    return tuple(_check_number(f"{where}[{i}]", v, meta) for i, v in enumerate(value))


def _build(name: str, raw: Mapping[str, Mapping[str, Any]], units: Mapping[str, Mapping[str, str]] | None
           ) -> WristParams:
    """Validate raw section dictionaries (values only) and build the frozen parameter set."""
    sections = {}
    for section, cls in _SECTIONS.items():
        values = raw.get(section, {})
        missing = [k for k in _field_names(cls) if k not in values]
        if missing:
            raise ParamsError(f"preset '{name}': missing parameter(s) {', '.join(f'{section}.{k}' for k in missing)}")
        kwargs = {}
        for key in _field_names(cls):
            meta = _meta(cls, key)
            where = f"{section}.{key}"
            if units is not None and units[section][key] != meta["unit"]:
                raise ParamsError(f"'{where}' must be given in {meta['unit']}, the file says "
                                  f"{units[section][key]!r}")
            kwargs[key] = _check_value(where, values[key], meta)
        sections[section] = cls(**kwargs)
    rom = sections["range_of_motion"]
    for lo, hi in (("rud_min", "rud_max"), ("fe_min", "fe_max"), ("ps_min", "ps_max")):
        if getattr(rom, lo) >= getattr(rom, hi):
            raise ParamsError(f"'range_of_motion.{lo}' must be below 'range_of_motion.{hi}'")
    return WristParams(name=name, **sections)


def _read_yaml(path: Path) -> dict:
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ParamsError(f"parameter file {path} is not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ParamsError(f"parameter file {path} must hold a mapping of sections, got {type(data).__name__}")
    return data


def _resolve(source: str | Path, seen: tuple[Path, ...] = ()) -> tuple[dict, dict]:
    """Read a preset (following ``base``) into (values, units) dictionaries."""
    path = _preset_path(source)
    if path in seen:
        raise ParamsError(f"parameter file {path} inherits from itself through 'base'")
    data = _read_yaml(path)
    values: dict[str, dict] = {s: {} for s in _SECTIONS}
    units: dict[str, dict] = {s: {} for s in _SECTIONS}
    base = data.pop("base", None)
    if base is not None:
        if not isinstance(base, str):
            raise ParamsError(f"{path}: 'base' must name a preset, got {base!r}")
        base_values, base_units = _resolve(base if base in PRESETS else path.parent / base, seen + (path,))
        for s in _SECTIONS:
            values[s].update(base_values[s])
            units[s].update(base_units[s])
    for section, entries in data.items():
        if section not in _SECTIONS:
            raise ParamsError(f"{path}: unknown section '{section}'; allowed: base, {', '.join(_SECTIONS)}")
        if not isinstance(entries, dict):
            raise ParamsError(f"{path}: section '{section}' must be a mapping of parameters")
        allowed = _field_names(_SECTIONS[section])
        for key, entry in entries.items():
            if key not in allowed:
                raise ParamsError(f"{path}: unknown parameter '{section}.{key}'; allowed: {', '.join(allowed)}")
            if not isinstance(entry, dict) or "value" not in entry or "unit" not in entry:
                raise ParamsError(f"{path}: '{section}.{key}' must be a mapping with 'value' and 'unit' "
                                  f"(and optionally 'reason'), got {entry!r}")
            extra = set(entry) - {"value", "unit", "reason"}
            if extra:
                raise ParamsError(f"{path}: '{section}.{key}' has unknown field(s) {sorted(extra)}; "
                                  f"allowed: value, unit, reason")
            values[section][key] = entry["value"]
            units[section][key] = str(entry["unit"])
    return values, units


def _preset_path(source: str | Path) -> Path:
    if isinstance(source, str) and source in PRESETS:
        return CONFIG_DIR / f"{source}.yaml"
    path = Path(source)
    if not path.is_file():
        raise ParamsError(f"unknown parameter preset or file {str(source)!r}; presets: {', '.join(PRESETS)}")
    return path.resolve()


_CACHE: dict[str, WristParams] = {}


def load_params(source: str | Path | WristParams | None = None) -> WristParams:
    """Load a preset by name ("paper", "paper_knm"), a YAML file path, or pass a WristParams through.

    ``None`` gives the default preset. Errors name the offending field and its allowed range.
    """
    if isinstance(source, WristParams):
        return source
    if source is None:
        source = DEFAULT_PRESET
    key = str(source)
    if key in PRESETS and key in _CACHE:
        return _CACHE[key]
    values, units = _resolve(source)
    name = key if key in PRESETS else Path(key).stem
    params = _build(name, values, units)
    if key in PRESETS:
        _CACHE[key] = params
    return params
