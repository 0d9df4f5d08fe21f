"""Hyperparameter files for PPO, SAC and recurrent PPO (ppo_lstm) in RL Zoo's format: one YAML per algorithm, keyed
by environment id.

A shipped file loads unchanged in `python -m rl_zoo3.train --conf-file FILE` and in `vswrist train`. An entry holds
only keys RL Zoo knows (n_timesteps, n_envs, policy, normalize, env_kwargs, policy_kwargs, frame_stack and the
algorithm's constructor arguments); `policy_kwargs` is written as RL Zoo writes it, a string such as
`"dict(net_arch=[64, 64], activation_fn=nn.Tanh)"`, which rl_zoo3 evaluates and this module parses with `ast`
(literals, `dict(...)` and allow-listed `nn.X` / `th.optim.X` names only: nothing in a file is executed). The run
settings RL Zoo takes as command-line flags (vec_env, eval_freq, n_eval_episodes, checkpoint_freq,
keep_checkpoints) live in a top-level `vswrist:` section keyed by the same ids, which rl_zoo3 never reads because it
reads only the entry of the id it trains.

Every key of an entry is consumed exactly once while resolving it (run keys here, algorithm keys by the
stable-baselines3 constructor, policy keys by the policy), and an unknown key is an error that names it, so a typo
cannot be silently ignored. A run directory's `config.yaml` stores the merged entry (run settings inside it), which
`resolve_entry` reads as well, as it reads files written before the split (run settings inside the entries,
`activation_fn` as a plain name).
"""

from __future__ import annotations

import ast
import copy
import inspect
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
ALGO_NAMES = ("ppo", "sac", "ppo_lstm")
# the policy class each algorithm takes (the observations are flat vectors); ppo_lstm is sb3-contrib's RecurrentPPO,
# named as RL Zoo names it: PPO with an LSTM, for tasks whose best action depends on what happened earlier
POLICIES = {"ppo": "MlpPolicy", "sac": "MlpPolicy", "ppo_lstm": "MlpLstmPolicy"}
RUN_SECTION = "vswrist"  # the top-level section of run settings that RL Zoo has no key for
# said when a hyperparameter file is missing: what the package ships, and where the studies' own files are (a
# study's tuned entries and sweeps are the repository's lab notebook, not package data)
WHERE_FILES_ARE = (f"the package ships {', '.join(f'{a}.yaml' for a in ALGO_NAMES)} in {CONFIG_DIR} "
                   "(the default of --config); a study's own hyperparameter and sweep files are in the repository's "
                   "experiments/<study>/, listed in experiments/README.md")

# Keys of an RL Zoo entry that configure the run rather than the algorithm, with their meaning.
ZOO_RUN_KEYS = {
    "n_timesteps": "total environment steps of training (int > 0)",
    "n_envs": "parallel environments (int > 0), run as the section's vec_env says",
    "policy": "stable-baselines3 policy class name (MlpPolicy; MlpLstmPolicy for ppo_lstm)",
    "normalize": "false, true, or VecNormalize options as a mapping or a dict(...) string (norm_obs, norm_reward, "
                 "clip_obs, clip_reward, epsilon)",
    "env_kwargs": "mapping passed to gymnasium.make",
    "policy_kwargs": "mapping passed to the policy, as RL Zoo writes it: a string \"dict(net_arch=[64, 64], "
                     "activation_fn=nn.Tanh)\"",
    "frame_stack": "observations stacked (int > 0; 1 = none): SB3's VecFrameStack over the normalised "
                   "observation, the newest last, as rl_zoo3 stacks",
}
# Run settings RL Zoo takes as command-line flags (in brackets): in the file's `vswrist:` section.
SECTION_KEYS = {
    "vec_env": "'batch' (default: one process, physics on threads), 'subproc' or 'dummy': how the n_envs "
               "environments are run (rl_zoo3 --vec-env takes subproc or dummy)",
    "eval_freq": "environment steps between periodic evaluations (int > 0; at most half the run) (rl_zoo3 --eval-freq)",
    "n_eval_episodes": "episodes per periodic evaluation (int > 0) (rl_zoo3 --eval-episodes)",
    "checkpoint_freq": "environment steps between checkpoints (int > 0) (rl_zoo3 --save-freq)",
    "keep_checkpoints": "how many of the newest checkpoints to keep on disk (int > 0) (rl_zoo3 keeps all)",
}
RUN_KEYS = {**ZOO_RUN_KEYS, **SECTION_KEYS}
# RL Zoo keys that `vswrist train` does not implement: named in the error instead of "unknown key".
ZOO_UNSUPPORTED = {"env_wrapper", "vec_env_wrapper", "callback", "monitor_kwargs", "noise_type",
                   "noise_std", "replay_buffer_class", "replay_buffer_kwargs"}
# Keys the training command sets itself; an entry may not set them.
RESERVED_ALGO_KEYS = {"self", "policy", "env", "tensorboard_log", "seed", "verbose", "device", "_init_setup_model",
                      "replay_buffer_class", "rollout_buffer_class"}
NORMALIZE_KEYS = {"norm_obs", "norm_reward", "clip_obs", "clip_reward", "epsilon"}
# Plain names accepted for activation_fn in a policy_kwargs mapping (files and run directories of earlier versions).
ACTIVATIONS = ("tanh", "relu", "elu", "leaky_relu")
# The only names a policy_kwargs string may use, as RL Zoo's files spell them (torch.nn as nn, torch as th).
ALLOWED_NAMES = {
    **{f"nn.{n}": ("torch.nn", n) for n in ("Tanh", "ReLU", "ELU", "LeakyReLU", "GELU", "SiLU", "Sigmoid",
                                             "Softplus", "Identity")},
    **{f"th.nn.{n}": ("torch.nn", n) for n in ("Tanh", "ReLU", "ELU", "LeakyReLU", "GELU", "SiLU")},
    **{f"th.optim.{n}": ("torch.optim", n) for n in ("Adam", "AdamW", "RMSprop", "SGD")},
}


class ConfigError(ValueError):
    """A hyperparameter file or entry is missing, malformed, or has a key outside the allowed set."""


@dataclass(frozen=True)
class RunConfig:
    """One resolved entry: run settings plus the keyword arguments of the algorithm's constructor."""

    env_id: str
    algo: str
    n_timesteps: int
    n_envs: int
    vec_env: str
    policy: str
    normalize: dict | None
    env_kwargs: dict
    eval_freq: int
    n_eval_episodes: int
    checkpoint_freq: int
    keep_checkpoints: int
    policy_kwargs: dict
    algo_kwargs: dict
    frame_stack: int = 1  # observations the policy sees at once (1: the current one only)
    source: str = ""
    raw: dict = field(default_factory=dict)

    def to_yaml_dict(self) -> dict:
        """The entry as written to a run directory: plain YAML that `resolve_entry` reads back unchanged."""
        out = copy.deepcopy(self.raw)
        out["n_timesteps"] = self.n_timesteps
        out["n_envs"] = self.n_envs
        out["vec_env"] = self.vec_env
        return out


def algo_class(algo: str):
    """The stable-baselines3 class for 'ppo' or 'sac', sb3-contrib's RecurrentPPO for 'ppo_lstm' (imported
    lazily: torch is heavy)."""
    if algo not in ALGO_NAMES:
        raise ConfigError(f"algo must be one of {', '.join(ALGO_NAMES)}, got {algo!r}")
    if algo == "ppo_lstm":
        from sb3_contrib import RecurrentPPO

        return RecurrentPPO
    import stable_baselines3

    return getattr(stable_baselines3, algo.upper())


def default_config_path(algo: str) -> Path:
    if algo not in ALGO_NAMES:
        raise ConfigError(f"algo must be one of {', '.join(ALGO_NAMES)}, got {algo!r}")
    return CONFIG_DIR / f"{algo}.yaml"


def read_mapping(path: Path, error: type[Exception], keys: tuple[str, ...], required: tuple[str, ...],
                 shape: str) -> dict:
    """The top-level mapping of a YAML file of this package's own formats (sweep and track files), with one-line
    errors of type ``error``: file missing, not YAML, not a mapping (``shape`` names its keys), a key outside
    ``keys``, a ``required`` key absent."""
    if not path.is_file():
        raise error("file not found")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise error(f"not valid YAML ({' '.join(str(exc).split())})") from None
    if not isinstance(doc, dict):
        raise error(f"must be a mapping of keys ({shape})")
    unknown = [k for k in doc if k not in keys]
    if unknown:
        raise error(f"unknown key '{unknown[0]}'; allowed: {', '.join(keys)}")
    for key in required:
        if key not in doc:
            raise error(f"'{key}' is required")
    return doc


def read_file(path: str | Path) -> tuple[dict, dict]:
    """(entries, run settings) of a hyperparameter file: the entries map environment ids to RL Zoo entries, the
    run settings are its `vswrist:` section (environment id -> mapping of SECTION_KEYS), empty when absent."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"hyperparameter file not found: {path} ({WHERE_FILES_ARE})")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"hyperparameter file {path} is not valid YAML: {exc}") from None
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise ConfigError(f"hyperparameter file {path} must map environment ids to mappings of hyperparameters")
    data = dict(data)
    section = data.pop(RUN_SECTION, None) or {}
    for env_id, settings in section.items():
        if env_id not in data:
            raise ConfigError(f"{path}: '{RUN_SECTION}.{env_id}' names no entry of the file; entries: "
                              f"{', '.join(sorted(data))}")
        if not isinstance(settings, dict):
            raise ConfigError(f"{path}: '{RUN_SECTION}.{env_id}' must be a mapping of {sorted(SECTION_KEYS)}, "
                              f"got {settings!r}")
        bad = sorted(set(settings) - set(SECTION_KEYS))
        if bad:
            raise ConfigError(f"{path}: '{RUN_SECTION}.{env_id}' has unknown key(s) {bad}; allowed: "
                              f"{sorted(SECTION_KEYS)} (algorithm keys belong in the entry '{env_id}')")
    return data, section


def load_file(path: str | Path) -> dict:
    """The entries of a hyperparameter file: a mapping from environment id to an RL Zoo entry."""
    return read_file(path)[0]


def load_config(algo: str, env_id: str, path: str | Path | None = None) -> RunConfig:
    """The resolved entry for `env_id` in the algorithm's file (default: the packaged `configs/<algo>.yaml`),
    with its run settings from the file's `vswrist:` section."""
    path = Path(path) if path is not None else default_config_path(algo)
    data, section = read_file(path)
    if env_id not in data:
        raise ConfigError(f"{path} has no entry for '{env_id}'; entries: {', '.join(sorted(data))}")
    entry = dict(data[env_id])
    settings = section.get(env_id, {})
    both = sorted(set(entry) & set(settings))
    if both:
        raise ConfigError(f"{path}: {both} set both in the entry '{env_id}' and in '{RUN_SECTION}.{env_id}'; "
                          f"keep one")
    entry.update(settings)
    return resolve_entry(algo, env_id, entry, source=str(path))


def zoo_train_args(algo: str, env_id: str, path: str | Path | None = None) -> list[str]:
    """The `python -m rl_zoo3.train` arguments that train `env_id` from the file as `vswrist train` does (seed,
    log folder and device left to the caller): the run settings of the `vswrist:` section as RL Zoo's flags."""
    path = Path(path) if path is not None else default_config_path(algo)
    cfg = load_config(algo, env_id, path)
    # RL Zoo has no batched vec env; its DummyVecEnv also keeps every world in one process.
    vec_env = "dummy" if cfg.vec_env == "batch" else cfg.vec_env
    return ["--algo", algo, "--env", env_id, "--gym-packages", "vswrist_gym", "--conf-file", str(path),
            "--vec-env", vec_env, "--eval-freq", str(cfg.eval_freq), "--eval-episodes", str(cfg.n_eval_episodes),
            "--save-freq", str(cfg.checkpoint_freq)]


def _positive_int(entry: dict, key: str, default: int | None = None) -> int:
    value = entry.pop(key, default)
    if value is None:
        raise ConfigError(f"'{key}' is required ({RUN_KEYS[key]})")
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ConfigError(f"'{key}' must be a positive integer ({RUN_KEYS[key]}), got {value!r}")
    return value


def parse_schedule(key: str, value: Any):
    """A number, or 'lin_<x>' for a linear decay from x to 0 over training (RL-Zoo notation, parsed, not evaluated)."""
    if isinstance(value, str) and value.startswith("lin_"):
        try:
            start = float(value[4:])
        except ValueError:
            raise ConfigError(f"'{key}': cannot read a number from {value!r} (expected e.g. lin_3e-4)") from None

        def schedule(progress_remaining: float, _start=start) -> float:
            return progress_remaining * _start

        return schedule
    return value


def _check_number(key: str, value: Any, default: Any) -> None:
    """An argument whose default is a number must be one (or, for a schedule, 'lin_<x>'): the algorithm would
    otherwise fail deep inside stable-baselines3. YAML 1.1, which PyYAML and RL Zoo read, takes 6e-4 (no decimal
    point) for text, the commonest way to get here."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f"'{key}' must be true or false, got {value!r}")
        return
    if not isinstance(default, (int, float)) or isinstance(value, (list, tuple)) \
            or (isinstance(value, (int, float)) and not isinstance(value, bool)):
        return  # a list is SB3's (frequency, unit) form of train_freq; other types are SB3's to judge
    if isinstance(value, str) and value.startswith("lin_"):
        return  # a schedule; parse_schedule reads it
    hint = ""
    if isinstance(value, str):
        try:
            hint = f" (YAML reads {value} as text: write it with a decimal point, {float(value):.1e})"
        except ValueError:
            pass
    raise ConfigError(f"'{key}' must be a number, got {value!r}{hint}")


_LITERALS = (int, float, str, bool, type(None))


def _dotted(node: ast.AST) -> str | None:
    """'nn.Tanh' for the AST of nn.Tanh; None for anything but a chain of plain names."""
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        head = _dotted(node.value)
        return f"{head}.{node.attr}" if head else None
    return None


def _literal(node: ast.AST, key: str, names: bool, text: str):
    """The value of one node of a dict(...) expression: literals, lists, tuples, dict(...) calls and dict displays
    with string keys, and (where `names`) an allow-listed dotted name. Anything else is refused unevaluated."""
    def refuse(why: str):
        frag = ast.get_source_segment(text, node) or ast.dump(node)
        raise ConfigError(f"'{key}': {why}: {frag!r} in {text!r} (allowed: numbers, strings, True/False/None, "
                          f"lists, dict(...)" + (", and the names in vswrist_gym.agents.hparams.ALLOWED_NAMES, e.g. nn.Tanh"
                                               if names else "")
                          + ")")

    if isinstance(node, ast.Constant):
        if isinstance(node.value, _LITERALS):
            return node.value
        refuse("a constant of an unsupported type")
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)) \
            and isinstance(node.operand, ast.Constant) and type(node.operand.value) in (int, float):
        return -node.operand.value if isinstance(node.op, ast.USub) else node.operand.value
    if isinstance(node, (ast.List, ast.Tuple)):
        items = [_literal(e, key, names, text) for e in node.elts]
        return items if isinstance(node, ast.List) else tuple(items)
    if isinstance(node, ast.Dict):
        out = {}
        for k, v in zip(node.keys, node.values):
            if not (isinstance(k, ast.Constant) and isinstance(k.value, str)):
                refuse("dictionary keys must be strings")
            out[k.value] = _literal(v, key, names, text)
        return out
    if isinstance(node, ast.Call):
        if not (isinstance(node.func, ast.Name) and node.func.id == "dict") or node.args \
                or any(kw.arg is None for kw in node.keywords):
            refuse("the only call allowed is dict(name=value, ...)")
        return {kw.arg: _literal(kw.value, key, names, text) for kw in node.keywords}
    if isinstance(node, (ast.Attribute, ast.Name)):
        dotted = _dotted(node)
        if names and dotted in ALLOWED_NAMES:
            import importlib

            module, attr = ALLOWED_NAMES[dotted]
            return getattr(importlib.import_module(module), attr)
        refuse("a name that is not allowed")
    refuse("an expression that is not a literal")


def parse_dict_string(key: str, text: str, names: bool = True) -> dict:
    """Parse RL Zoo's `"dict(a=1, b=nn.Tanh)"` notation without evaluating it (see `_literal` for what it takes)."""
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise ConfigError(f"'{key}': {text!r} is not a dict(...) expression ({exc.msg})") from None
    value = _literal(tree.body, key, names, text.strip())
    if not isinstance(value, dict):
        raise ConfigError(f"'{key}' must be a dict(...) expression or a mapping, got {text!r}")
    return value


def parse_policy_kwargs(value: Any) -> dict:
    """policy_kwargs as a mapping for the policy: RL Zoo's string form, or a mapping (activation_fn by plain name)."""
    if value is None:
        return {}
    if isinstance(value, str):
        return parse_dict_string("policy_kwargs", value)
    if not isinstance(value, dict):
        raise ConfigError(f"'policy_kwargs' must be a string such as \"dict(net_arch=[64, 64], activation_fn=nn.Tanh)\""
                          f" or a mapping, got {value!r}")
    out = copy.deepcopy(value)
    if "activation_fn" in out:
        name = out["activation_fn"]
        if name not in ACTIVATIONS:
            raise ConfigError(f"'policy_kwargs.activation_fn' must be one of {', '.join(ACTIVATIONS)} in a mapping "
                              f"(or nn.Tanh etc. in RL Zoo's string form), got {name!r}")
        import torch.nn as nn

        out["activation_fn"] = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU, "leaky_relu": nn.LeakyReLU}[name]
    return out


VEC_ENVS = ("batch", "subproc", "dummy")


# The two tracks of the benchmark (docs/training.md). "stiffness": the posture reference is the task's own and the
# policy sets only the stiffness (the residual action mode with posture_scale 0: its posture outputs are ignored);
# "full": posture and stiffness, as the entry's residual says (posture_scale > 0).
TRACKS = ("full", "stiffness")


def track_of(env_kwargs: dict) -> str:
    """The track an entry's env_kwargs train on: 'stiffness', 'full', or 'custom' (another action mode)."""
    if env_kwargs.get("action_mode") != "residual":
        return "custom"
    scale = (env_kwargs.get("residual") or {}).get("posture_scale")
    if scale is None:  # the environment's default residual, which trims the posture
        return "full"
    return "stiffness" if float(scale) == 0.0 else "full"


def with_track(cfg: "RunConfig", track: str | None) -> "RunConfig":
    """The config on `track` (None: as the entry says). The stiffness track sets residual.posture_scale to 0; the
    full track keeps the entry's posture residual and refuses an entry that has none."""
    if track is None:
        return cfg
    if track not in TRACKS:
        raise ConfigError(f"track must be one of {', '.join(TRACKS)}, got {track!r}")
    kwargs = copy.deepcopy(cfg.env_kwargs)
    if kwargs.get("action_mode", "residual") != "residual":
        raise ConfigError(f"the {track} track needs env_kwargs.action_mode 'residual', the entry of {cfg.env_id} "
                          f"has {kwargs['action_mode']!r}")
    kwargs["action_mode"] = "residual"
    if track == "stiffness":
        kwargs["residual"] = {**(kwargs.get("residual") or {}), "posture_scale": 0.0}
    elif track_of(kwargs) != "full":
        raise ConfigError(f"the entry of {cfg.env_id} is stiffness-only (residual.posture_scale 0); the full track "
                          "needs a posture_scale > 0 in env_kwargs.residual")
    raw = copy.deepcopy(cfg.raw)
    raw["env_kwargs"] = kwargs
    return replace(cfg, env_kwargs=kwargs, raw=raw)


def resolve_entry(algo: str, env_id: str, entry: dict, source: str = "") -> RunConfig:
    """Check and split one entry; every key is consumed here or validated against the algorithm's constructor."""
    cls = algo_class(algo)
    raw = copy.deepcopy(entry)
    entry = copy.deepcopy(entry)
    n_timesteps = _positive_int(entry, "n_timesteps")
    n_envs = _positive_int(entry, "n_envs", 1)
    vec_env = entry.pop("vec_env", "batch")
    if vec_env not in VEC_ENVS:
        raise ConfigError(f"'vec_env' must be one of {list(VEC_ENVS)}, got {vec_env!r}")
    policy = entry.pop("policy", POLICIES[algo])
    if policy != POLICIES[algo]:
        raise ConfigError(f"'policy' must be '{POLICIES[algo]}' for {algo} (the observations are flat vectors), "
                          f"got {policy!r}")
    normalize = entry.pop("normalize", False)
    if isinstance(normalize, str):  # RL Zoo's "dict(norm_obs=True, norm_reward=False)"
        normalize = parse_dict_string("normalize", normalize, names=False)
    if normalize is True:
        normalize = {}
    elif normalize is False or normalize is None:
        normalize = None
    elif isinstance(normalize, dict):
        bad = set(normalize) - NORMALIZE_KEYS
        if bad:
            raise ConfigError(f"'normalize' has unknown keys {sorted(bad)}; allowed: {sorted(NORMALIZE_KEYS)}")
    else:
        raise ConfigError(f"'normalize' must be true, false, a mapping or a dict(...) string, got {normalize!r}")
    env_kwargs = entry.pop("env_kwargs", None) or {}
    if not isinstance(env_kwargs, dict):
        raise ConfigError(f"'env_kwargs' must be a mapping, got {env_kwargs!r}")
    eval_freq = _positive_int(entry, "eval_freq", max(n_timesteps // 10, 1))
    n_eval_episodes = _positive_int(entry, "n_eval_episodes", 5)
    checkpoint_freq = _positive_int(entry, "checkpoint_freq", max(n_timesteps // 5, 1))
    keep_checkpoints = _positive_int(entry, "keep_checkpoints", 2)
    policy_kwargs = parse_policy_kwargs(entry.pop("policy_kwargs", None))
    frame_stack = _positive_int(entry, "frame_stack", 1)

    zoo_only = sorted(set(entry) & ZOO_UNSUPPORTED)
    if zoo_only:
        raise ConfigError(f"{source or 'entry'} [{env_id}]: RL Zoo key(s) {zoo_only} are not supported by vswrist "
                          f"train (it takes {sorted(RUN_KEYS)} and {algo.upper()} arguments)")
    params = inspect.signature(cls.__init__).parameters
    allowed = set(params) - RESERVED_ALGO_KEYS
    bad = sorted(set(entry) - allowed)
    if bad:
        raise ConfigError(
            f"{source or 'entry'} [{env_id}]: unknown key(s) {bad} for {algo.upper()}; allowed: "
            f"run keys {sorted(RUN_KEYS)} and {algo.upper()} arguments {sorted(allowed - {'policy_kwargs'})}"
        )
    for key, value in entry.items():
        _check_number(key, value, params[key].default)
    algo_kwargs = {k: parse_schedule(k, v) for k, v in entry.items()}
    return RunConfig(env_id=env_id, algo=algo, n_timesteps=n_timesteps, n_envs=n_envs, vec_env=vec_env,
                     policy=policy, normalize=normalize, env_kwargs=env_kwargs, eval_freq=eval_freq,
                     n_eval_episodes=n_eval_episodes, checkpoint_freq=checkpoint_freq,
                     keep_checkpoints=keep_checkpoints, policy_kwargs=policy_kwargs, algo_kwargs=algo_kwargs,
                     frame_stack=frame_stack, source=source, raw=raw)
