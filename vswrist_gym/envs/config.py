"""Environment settings: YAML files per task over shared defaults, with user overrides, validated.

``vswrist_gym/configs/envs/defaults.yaml`` holds the settings every task shares; ``<task>.yaml`` overrides
some of them and holds the task's own ``task`` section. Keyword arguments of ``gymnasium.make`` override both
(nested dictionaries merge). Every value is checked here, so a typo or an out-of-range number fails at
construction with the field name and the allowed range, never mid-episode.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any, Mapping

import yaml

from ..model.builder import OFFSCREEN_SIZE
from ..params import CONFIG_DIR

ENV_CONFIG_DIR = CONFIG_DIR / "envs"
ACTION_MODES = ("posture_stiffness", "posture_compliance", "motor", "residual")
OBS_MODES = ("flat", "dict")
STIFFNESS_MAPS = ("asinh", "linear")
SCALE_TERMS = ("spring_K", "spring_delta0", "motor_time_constant", "link_mass", "hand_mass", "damping",
               "tool_mass", "friction")
NOISE_KEYS = ("posture", "posture_rate", "force", "torque")


class EnvConfigError(ValueError):
    """An environment setting is unknown, of the wrong type, or out of range."""


def _read(path: Path) -> dict:
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError as exc:
        raise EnvConfigError(f"environment config file {path} does not exist") from exc
    except yaml.YAMLError as exc:
        raise EnvConfigError(f"environment config file {path} is not valid YAML: {exc}") from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise EnvConfigError(f"environment config file {path} must hold a mapping, got {type(data).__name__}")
    return data


def merge(base: Mapping[str, Any], override: Mapping[str, Any]) -> dict:
    """Deep merge: dictionaries merge key by key, anything else in ``override`` replaces."""
    out = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def number(where: str, value: Any, lo: float | None = None, hi: float | None = None, *,
           lo_open: bool = False, integer: bool = False) -> float:
    """A finite number in [lo, hi] (or (lo, hi] with ``lo_open``), else an error naming ``where``."""
    ok_type = isinstance(value, int) if integer else isinstance(value, (int, float))
    left = "(" if lo_open else "["
    rng = f"{left}{'-inf' if lo is None else f'{lo:g}'}, {'inf' if hi is None else f'{hi:g}'}]"
    if isinstance(value, bool) or not ok_type:
        kind = "an integer" if integer else "a number"
        raise EnvConfigError(f"'{where}' must be {kind} in {rng}, got {value!r}")
    v = float(value)
    if (not math.isfinite(v) or (lo is not None and (v <= lo if lo_open else v < lo))
            or (hi is not None and v > hi)):
        raise EnvConfigError(f"'{where}' = {v:g} is outside the allowed range {rng}")
    return int(value) if integer else v


def interval(where: str, value: Any, lo: float | None = None, hi: float | None = None, *,
             integer: bool = False) -> tuple:
    """A pair [a, b] with lo <= a <= b <= hi."""
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise EnvConfigError(f"'{where}' must be a pair [low, high] within [{lo}, {hi}], got {value!r}")
    a = number(f"{where}[0]", value[0], lo, hi, integer=integer)
    b = number(f"{where}[1]", value[1], lo, hi, integer=integer)
    if a > b:
        raise EnvConfigError(f"'{where}' = {list(value)}: low must not exceed high")
    return a, b


def choice(where: str, value: Any, allowed: tuple[str, ...]) -> str:
    if value not in allowed:
        raise EnvConfigError(f"'{where}' = {value!r} is not allowed; choose one of {list(allowed)}")
    return value


def _keys(where: str, given: Mapping[str, Any], allowed) -> None:
    unknown = sorted(set(given) - set(allowed), key=str)
    if unknown:
        raise EnvConfigError(f"unknown setting(s) {', '.join(f'{where}{k}' for k in unknown)}; "
                             f"allowed: {sorted(allowed)}")


def sections(where: str, cfg: Mapping[str, Any], reference: Mapping[str, Any]) -> None:
    """Every setting that is a mapping in ``reference`` (a section, at any depth) must be a mapping in
    ``cfg`` too; an override that replaces a section by a number, a string or a list fails here, naming the
    dotted field, instead of deep inside the validation."""
    for key, ref in reference.items():
        if not isinstance(ref, Mapping) or key not in cfg:
            continue
        name, value = f"{where}{key}", cfg[key]
        if not isinstance(value, Mapping):
            keys = list(ref)
            shown = ", ".join(map(str, keys[:4])) + (", ..." if len(keys) > 4 else "")
            raise EnvConfigError(f"'{name}' must be a mapping of settings ({shown}), "
                                 f"got {type(value).__name__} {value!r}")
        sections(f"{name}.", value, ref)


def load_env_config(task: str, overrides: Mapping[str, Any] | None = None) -> dict:
    """Defaults, then ``<task>.yaml``, then ``overrides``; the common sections validated (``task`` is
    validated by the task class, ``reward``/``observation`` names by the environment)."""
    defaults = _read(ENV_CONFIG_DIR / "defaults.yaml")
    reference = merge(defaults, _read(ENV_CONFIG_DIR / f"{task}.yaml"))
    cfg = reference
    if overrides is not None:
        if not isinstance(overrides, Mapping):
            raise EnvConfigError(f"'config' must be a mapping of settings (e.g. {{'reward': {{'energy': 0.5}}}}), "
                                 f"got {type(overrides).__name__} {overrides!r}")
        cfg = merge(reference, overrides)
    allowed = set(defaults) | {"task"}
    _keys("", cfg, allowed)
    sections("", cfg, reference)
    cfg.setdefault("task", {})
    validate_common(cfg, defaults)
    return cfg


def validate_common(cfg: dict, defaults: Mapping[str, Any]) -> None:
    if not isinstance(cfg["params"], str):
        raise EnvConfigError(f"'params' must name a device preset or a YAML path, got {cfg['params']!r}")
    if not isinstance(cfg["gravity_compensation"], bool):
        raise EnvConfigError(f"'gravity_compensation' must be true or false, got {cfg['gravity_compensation']!r}")
    if not isinstance(cfg["compensate_tool"], bool):
        raise EnvConfigError(f"'compensate_tool' must be true or false, got {cfg['compensate_tool']!r}")
    cfg["ctrl_dt"] = number("ctrl_dt", cfg["ctrl_dt"], 0.0, 0.1, lo_open=True)
    if cfg["physics_dt"] is not None:
        cfg["physics_dt"] = number("physics_dt", cfg["physics_dt"], 0.0, cfg["ctrl_dt"], lo_open=True)
    cfg["episode_s"] = number("episode_s", cfg["episode_s"], cfg["ctrl_dt"], 600.0)
    cfg["settle_s"] = number("settle_s", cfg["settle_s"], 0.0, 60.0)
    # a weld opening is at most pi rad (an angle) or a few link lengths (m), so 10 never triggers
    cfg["closure_warn"] = number("closure_warn", cfg["closure_warn"], 0.0, 10.0, lo_open=True)
    if not isinstance(cfg["closure_truncate"], bool):
        raise EnvConfigError(f"'closure_truncate' must be true or false, got {cfg['closure_truncate']!r}")
    choice("action_mode", cfg["action_mode"], ACTION_MODES)
    choice("obs_mode", cfg["obs_mode"], OBS_MODES)
    choice("stiffness_map", cfg["stiffness_map"], STIFFNESS_MAPS)
    obs = cfg["observation"]
    if not isinstance(obs, (list, tuple)) or not obs or not all(isinstance(n, str) for n in obs):
        raise EnvConfigError(f"'observation' must be a non-empty list of term names, got {obs!r}")
    if len(set(obs)) != len(obs):
        raise EnvConfigError(f"'observation' lists a term twice: {obs}")
    if not isinstance(cfg["reward"], Mapping) or not cfg["reward"]:
        raise EnvConfigError("'reward' must map reward term names to weights")
    for name, w in cfg["reward"].items():
        cfg["reward"][name] = number(f"reward.{name}", w, 0.0, 1e6)
    _keys("scales.", cfg["scales"], defaults["scales"])
    for name, v in cfg["scales"].items():
        cfg["scales"][name] = number(f"scales.{name}", v, 0.0, 1e6, lo_open=True)
    _keys("residual.", cfg["residual"], defaults["residual"])
    number("residual.posture_scale", cfg["residual"]["posture_scale"], 0.0, math.pi)  # 0: stiffness-only residual
    number("residual.stiffness_scale", cfg["residual"]["stiffness_scale"], 0.0, 2.0)  # 0: posture-only residual
    number("residual.stiffness_nominal", cfg["residual"]["stiffness_nominal"], -1.0, 1.0)
    _keys("compliance.", cfg["compliance"], defaults["compliance"])
    cmin = number("compliance.min", cfg["compliance"]["min"], 0.0, 1e3, lo_open=True)
    number("compliance.max", cfg["compliance"]["max"], cmin, 1e3, lo_open=True)
    _keys("render.", cfg["render"], defaults["render"])
    number("render.width", cfg["render"]["width"], 16, OFFSCREEN_SIZE[0], integer=True)
    number("render.height", cfg["render"]["height"], 16, OFFSCREEN_SIZE[1], integer=True)
    if not isinstance(cfg["render"]["camera"], str):
        raise EnvConfigError(f"'render.camera' must be a camera name, got {cfg['render']['camera']!r}")
    rnd = cfg["randomize"]
    _keys("randomize.", rnd, defaults["randomize"])
    for term, spec in rnd.items():
        if not isinstance(spec, Mapping) or not isinstance(spec.get("enabled"), bool):
            raise EnvConfigError(f"'randomize.{term}' must be a mapping with 'enabled: true|false'")
        if term in SCALE_TERMS:
            _keys(f"randomize.{term}.", spec, ("enabled", "range"))
            interval(f"randomize.{term}.range", spec["range"], 0.05, 20.0)
        elif term == "latency":
            _keys("randomize.latency.", spec, ("enabled", "range"))
            interval("randomize.latency.range", spec["range"], 0.0, cfg["ctrl_dt"])
        elif term == "sensor_noise":
            _keys("randomize.sensor_noise.", spec, ("enabled",) + NOISE_KEYS)
            for k in NOISE_KEYS:
                number(f"randomize.sensor_noise.{k}", spec[k], 0.0, 100.0)


def validate_task(cfg_task: Mapping[str, Any], spec: Mapping[str, tuple], task: str) -> dict:
    """Check a task section against ``spec``: name -> ("number"|"interval"|"int_interval", lo, hi) or
    ("choice", allowed names, None)."""
    _keys("task.", cfg_task, spec)
    missing = sorted(set(spec) - set(cfg_task))
    if missing:
        raise EnvConfigError(f"task '{task}' is missing setting(s) {', '.join('task.' + m for m in missing)}")
    out = {}
    for key, (kind, lo, hi) in spec.items():
        where = f"task.{key}"
        if kind == "number":
            out[key] = number(where, cfg_task[key], lo, hi)
        elif kind == "interval":
            out[key] = interval(where, cfg_task[key], lo, hi)
        elif kind == "int_interval":
            out[key] = interval(where, cfg_task[key], lo, hi, integer=True)
        elif kind == "choice":
            out[key] = choice(where, cfg_task[key], lo)
        else:  # pragma: no cover - programming error
            raise AssertionError(kind)
    return out
