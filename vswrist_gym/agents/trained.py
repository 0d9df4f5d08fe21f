"""A trained run as an agent: a `vswrist train` run directory or an RL Zoo experiment folder (its config.yml and
args.yml read with a YAML loader that admits only the OrderedDict tag rl_zoo3 writes), loaded with its own
normalisation statistics and checked against the environment it is asked to drive."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from vswrist_gym.agents.checkpoints import checkpoint_step, final_model_step, latest_checkpoint, load_model
from vswrist_gym.agents.fileio import RunDirError
from vswrist_gym.agents.hparams import ALGO_NAMES, ConfigError, RunConfig, resolve_entry
from vswrist_gym.agents.run_config import read_config
from vswrist_gym.agents.run_stats import load_vecnormalize


ZOO_CONFIG_FILE, ZOO_ARGS_FILE, ZOO_VECNORM_FILE = "config.yml", "args.yml", "vecnormalize.pkl"


class _ZooYamlLoader(yaml.SafeLoader):
    """SafeLoader plus the one Python tag rl_zoo3 writes into config.yml and args.yml (an OrderedDict, as a list
    of key-value pairs); any other Python tag stays an error, so reading the files runs nothing."""


def _ordered_dict(loader, node):
    if not isinstance(node, yaml.SequenceNode):
        raise yaml.constructor.ConstructorError(None, None, "an OrderedDict that is not a list of pairs",
                                                node.start_mark)
    args = loader.construct_sequence(node, deep=True)  # [[[key, value], ...]]: the constructor's one argument
    return {k: v for k, v in (args[0] if args else [])}


_ZooYamlLoader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict", _ordered_dict)


def zoo_params_folder(folder: Path) -> Path | None:
    """The parameters folder (config.yml, args.yml, vecnormalize.pkl) of an RL Zoo experiment folder such as
    logs/ppo/VSWrist-Polish-v1_1, or None when `folder` is not one."""
    folder = Path(folder)
    if not folder.is_dir():
        return None
    found = [p for p in sorted(folder.iterdir()) if p.is_dir() and (p / ZOO_ARGS_FILE).is_file()
             and (p / ZOO_CONFIG_FILE).is_file()]
    return found[0] if len(found) == 1 else None


def read_zoo_run(folder: Path) -> tuple[RunConfig, int, Path]:
    """(config, seed, parameters folder) of an RL Zoo experiment folder, from the files rl_zoo3 wrote: the env id,
    algorithm and seed from args.yml, the entry (env_kwargs, normalize, ...) from config.yml. env_kwargs follow
    rl_zoo3.enjoy: the entry's, replaced by args.yml's --env-kwargs when those were given."""
    params = zoo_params_folder(folder)
    if params is None:
        raise RunDirError(f"{folder} is not an RL Zoo experiment folder (no <env>/{ZOO_ARGS_FILE} and "
                          f"<env>/{ZOO_CONFIG_FILE} in it)")
    try:
        args = yaml.load((params / ZOO_ARGS_FILE).read_text(), Loader=_ZooYamlLoader)
        hyper = yaml.load((params / ZOO_CONFIG_FILE).read_text(), Loader=_ZooYamlLoader)
        algo, env_id = str(args["algo"]).lower(), str(args["env"])
        seed = int(args.get("seed", 0) or 0)
        if not isinstance(hyper, dict):
            raise TypeError(f"{ZOO_CONFIG_FILE} holds a {type(hyper).__name__}, not the entry")
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise RunDirError(f"{params}: RL Zoo files not readable ({type(exc).__name__}: {exc})") from None
    if algo not in ALGO_NAMES:
        raise RunDirError(f"{folder}: an RL Zoo {algo.upper()} run; vswrist evaluates {', '.join(ALGO_NAMES)} runs "
                          f"only")
    hyper = dict(hyper)
    if args.get("env_kwargs") is not None:
        hyper["env_kwargs"] = args["env_kwargs"]
    # keys that shape training but not the policy's inputs or outputs: the model file holds the network itself,
    # so these need not be understood to replay it (env_wrapper and the like do change what the policy sees, and
    # stay errors; frame_stack is replayed as rl_zoo3 trains it)
    for key in ("policy_kwargs", "callback", "monitor_kwargs", "noise_type", "noise_std", "replay_buffer_class",
                "replay_buffer_kwargs"):
        hyper.pop(key, None)
    normalize = hyper.get("normalize")
    if isinstance(normalize, dict):  # rl_zoo3 adds the algorithm's gamma (reward normalisation only)
        hyper["normalize"] = {k: v for k, v in normalize.items() if k != "gamma"}
    try:
        cfg = resolve_entry(algo, env_id, hyper, source=str(params / ZOO_CONFIG_FILE))
    except ConfigError as exc:
        raise RunDirError(f"{params / ZOO_CONFIG_FILE}: {exc}") from None
    return cfg, seed, params


def resolve_agent_path(text: str | Path) -> tuple[Path, str | None]:
    """(run folder, checkpoint implied by the file) for what a user names as a trained agent: a vswrist run
    directory, an RL Zoo experiment folder, or a model file inside either. A model file anywhere else is refused:
    it does not say which action mode or normalisation statistics it was trained with."""
    path = Path(text)
    if path.is_dir() or path.suffix != ".zip":
        return path, None
    if not path.is_file():
        raise RunDirError(f"model file not found: {path}")
    parent = path.parent
    if (parent / "config.yaml").is_file() and path.name == "model.zip":
        return parent, "final"
    if parent.name == "eval" and (parent.parent / "config.yaml").is_file() and path.name == "best_model.zip":
        return parent.parent, "best"
    params = zoo_params_folder(parent)
    if params is not None and path.name == f"{params.name}.zip":
        return parent, "final"
    if params is not None and path.name == "best_model.zip":
        return parent, "best"
    raise RunDirError(f"{path}: a model file alone does not say the action mode and normalisation it was trained "
                      f"with; give its run directory (vswrist train) or RL Zoo experiment folder (logs/<algo>/<env>_N)")


def env_config_mismatch(env, env_kwargs: dict) -> str | None:
    """None when `env` was built with the settings `env_kwargs` give (rendering aside); otherwise the first
    setting that differs, as 'key: trained with X, the environment has Y'. Environments without a resolved
    `cfg` (not VS-Wrist tasks) are compared through their spaces only, by the caller."""
    import gymnasium as gym

    have = getattr(env.unwrapped, "cfg", None)
    if not isinstance(have, dict) or env.spec is None:
        return None
    ref = gym.make(env.spec.id, **env_kwargs)
    try:
        want = ref.unwrapped.cfg
    finally:
        ref.close()

    def first_diff(a, b, where=""):
        if isinstance(a, dict) and isinstance(b, dict):
            for key in sorted(set(a) | set(b), key=lambda k: (k != "action_mode", str(k))):
                if not where and key == "render":
                    continue
                diff = first_diff(a.get(key), b.get(key), f"{where}.{key}" if where else str(key))
                if diff:
                    return diff
            return None
        same = a == b
        if isinstance(same, np.ndarray):
            same = bool(np.all(same))
        return None if same else f"{where}: trained with {a!r}, the environment has {b!r}"

    return first_diff(want, have)


class TrainedAgent:
    """A trained run (a `vswrist train` run directory or an RL Zoo experiment folder) as an agent with the SB3
    `predict` interface on raw (unnormalised) observations, with the run's own normalisation statistics."""

    def __init__(self, run_dir: str | Path, checkpoint: str = "newest"):
        from gymnasium import spaces

        run_dir, implied = resolve_agent_path(run_dir)
        if implied is not None:
            checkpoint = implied
        self.run_dir = Path(run_dir)
        if not self.run_dir.is_dir():
            raise RunDirError(f"run directory not found: {self.run_dir}")
        self.kind = "vswrist"
        self.note = None  # a line to show the user when the model evaluated is not the run's newest
        if not (self.run_dir / "config.yaml").is_file() and zoo_params_folder(self.run_dir) is not None:
            self.kind = "rl_zoo"
            self.cfg, self.seed, params = read_zoo_run(self.run_dir)
            name = {"final": f"{params.name}.zip", "newest": f"{params.name}.zip",
                    "best": "best_model.zip"}.get(checkpoint)
            if name is None:
                raise RunDirError(f"--checkpoint {checkpoint}: an RL Zoo folder has its final model and "
                                  f"best_model.zip (final or best)")
            model_path, stats = self.run_dir / name, params / ZOO_VECNORM_FILE
        else:
            self.cfg, self.seed = read_config(self.run_dir)
            model_path, stats = self._vswrist_files(checkpoint)
        self.model_path = model_path
        self.model = load_model(model_path, self.cfg.algo)
        self.vecnorm = None
        if self.cfg.normalize is not None:
            self.vecnorm = load_vecnormalize(stats, None)
            self.vecnorm.training = False
        if not isinstance(self.model.observation_space, spaces.Box):
            raise RunDirError(f"{self.run_dir}: unsupported observation space {self.model.observation_space}")
        self.frame_stack = self.cfg.frame_stack
        self._stack = None  # the stacked frames, one row per environment, built at the first query

    @property
    def observation_shape(self) -> tuple:
        """The shape of one environment observation the policy was trained on (the model sees frame_stack of
        them side by side, the newest last, as VecFrameStack stacks flat observations)."""
        shape = tuple(self.model.observation_space.shape)
        if self.frame_stack > 1:
            if shape[-1] % self.frame_stack:
                raise RunDirError(f"{self.run_dir}: model observations of shape {shape} do not split into "
                                  f"frame_stack {self.frame_stack} frames")
            shape = (*shape[:-1], shape[-1] // self.frame_stack)
        return shape

    def _vswrist_files(self, checkpoint: str) -> tuple[Path, Path]:
        final_step, latest = final_model_step(self.run_dir), latest_checkpoint(self.run_dir)
        latest_step = checkpoint_step(latest)
        # a run without model.zip never finished: "newest" then stays "final" and says how to evaluate its last
        # checkpoint (--checkpoint latest), so that a cut-off run is not taken for a finished one
        has_final = (self.run_dir / "model.zip").exists()
        newer = latest if has_final and latest is not None and latest_step is not None and (
            final_step is None or latest_step > final_step) else None
        if checkpoint == "newest":
            checkpoint = "final" if newer is None else "latest"
            if newer is not None:
                self.note = (f"{self.run_dir}: evaluating {newer.relative_to(self.run_dir)} (step {latest_step}), "
                             f"the newest model run.json accounts for; model.zip holds the older step "
                             f"{final_step if final_step is not None else 'unknown'} (--checkpoint final for it)")
        elif checkpoint == "final" and newer is not None:
            self.note = (f"{self.run_dir}: evaluating model.zip (step {final_step if final_step is not None else '?'})"
                         f" as asked; the run went on to step {latest_step} ({newer.relative_to(self.run_dir)})")
        if checkpoint == "final":
            folder = self.run_dir
            if not (folder / "model.zip").exists():
                latest = latest_checkpoint(self.run_dir)
                hint = (f"; the run did not finish: resume it with `vswrist train ... --out {self.run_dir} --resume`"
                        f" or evaluate its last checkpoint with --checkpoint latest") if latest else ""
                raise RunDirError(f"model file not found: {folder / 'model.zip'}{hint}")
        elif checkpoint == "latest":
            folder = latest_checkpoint(self.run_dir)
            if folder is None:
                raise RunDirError(f"no complete checkpoint in {self.run_dir / 'checkpoints'}")
        elif checkpoint == "best":
            folder = self.run_dir / "eval"
            if not (folder / "best_model.zip").exists():
                raise RunDirError(f"no best model in {folder} (periodic evaluation never ran)")
        else:
            raise ValueError(f"checkpoint must be newest, final, latest or best, got {checkpoint!r}")
        name = "best_model.zip" if checkpoint == "best" else "model.zip"
        return folder / name, (self.run_dir if checkpoint == "best" else folder)

    @property
    def env_id(self) -> str:
        return self.cfg.env_id

    def check_env(self, env) -> None:
        """The environment must be the one the run was trained on: same spaces and, for a VS-Wrist task, the same
        resolved settings (action mode above all), so that a policy never drives an environment it does not know."""
        if env.observation_space.shape != self.observation_shape:
            raise RunDirError(f"{self.run_dir} was trained on observations of shape "
                              f"{self.observation_shape}, the environment gives "
                              f"{env.observation_space.shape}")
        if env.action_space != self.model.action_space:
            raise RunDirError(f"{self.run_dir} was trained with actions in {self.model.action_space}, the "
                              f"environment takes {env.action_space}")
        diff = env_config_mismatch(env, self.cfg.env_kwargs)
        if diff:
            raise RunDirError(f"{self.run_dir} does not match the environment: {diff} (build it with the run's "
                              f"env_kwargs {self.cfg.env_kwargs})")
        if self.vecnorm is not None and self.vecnorm.norm_obs and \
                np.shape(self.vecnorm.obs_rms.mean) != env.observation_space.shape:
            raise RunDirError(f"{self.run_dir}: normalisation statistics of shape {np.shape(self.vecnorm.obs_rms.mean)}"
                              f" for observations of shape {env.observation_space.shape}")

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        """The action for `obs` (one observation or a batch, one row per environment). With frame stacking the
        agent keeps each environment's last frames as VecFrameStack does in training: a row whose
        `episode_start` is true starts from zeros with its observation newest. Without `episode_start` (a caller
        that runs one episode, as `vswrist video` does) every row starts at the first query and continues after."""
        if self.vecnorm is not None and self.vecnorm.norm_obs:
            obs = self.vecnorm.normalize_obs(np.asarray(obs, dtype=np.float32))
        if self.frame_stack <= 1:
            return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        obs = np.asarray(obs, dtype=np.float32)
        single = obs.shape == self.observation_shape
        rows = obs.reshape(1, *obs.shape) if single else obs
        starts = np.zeros(len(rows), dtype=bool) if episode_start is None else \
            np.asarray(episode_start, dtype=bool).reshape(len(rows))
        width = rows.shape[-1]
        if self._stack is None or self._stack.shape[0] != len(rows):
            self._stack = np.zeros((len(rows), *rows.shape[1:-1], width * self.frame_stack), dtype=np.float32)
            starts = np.ones(len(rows), dtype=bool)
        # VecFrameStack's update of flat observations: every row shifts by one frame, a row whose episode starts
        # is zeroed, and the new frames go last
        self._stack = np.roll(self._stack, -width, axis=-1)
        self._stack[starts] = 0.0
        self._stack[..., -width:] = rows
        stacked = self._stack.copy()
        action, state = self.model.predict(stacked, state=state, episode_start=episode_start,
                                           deterministic=deterministic)
        return (action[0] if single else action), state
