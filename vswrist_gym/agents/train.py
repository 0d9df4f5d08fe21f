"""`vswrist train`: train a PPO or SAC posture-and-stiffness policy on a task, into a self-describing run directory.

Example: `vswrist train --task LoadHold --algo ppo --timesteps 50000 --seed 0 --out runs/loadhold_ppo_0`.
The run directory layout is described in `vswrist_gym.agents.runs`; `--resume` continues from its last checkpoint.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from vswrist_gym.agents.hparams import ALGO_NAMES, ConfigError, RunConfig, load_config
from vswrist_gym.agents.runs import (RunDirError, atomic_write_bytes, check_env_id, check_env_kwargs, latest_checkpoint,
                                     limit_threads, load_model, load_vecnormalize, make_vec_env, model_bytes,
                                     override, read_config, save_checkpoint, update_run_json, versions,
                                     wrap_normalize, write_config)

class TrainingError(RuntimeError):
    """Training stopped because the environment or a worker failed; the run dir keeps its last checkpoint."""


EVAL_SEED_OFFSET = 10_000  # periodic-evaluation environments never share seeds with the training environments


def task_id(name: str) -> str:
    """Accept a full id ('VSWrist/Polish-v0', 'Pendulum-v1') or a VSWrist short name ('Polish')."""
    import gymnasium as gym

    import vswrist_gym  # noqa: F401  (registers the VSWrist/ ids)

    if name in gym.registry:
        return name
    for candidate in (f"VSWrist/{name}-v0", f"VSWrist/{name}"):
        if candidate in gym.registry:
            return candidate
    check_env_id(name)  # raises a ConfigError listing the registered tasks
    return name


def _callbacks(run_dir: Path, cfg: RunConfig, n_envs: int, seed: int, resumed: bool):
    from stable_baselines3.common.callbacks import BaseCallback, EvalCallback

    class HistoryEvalCallback(EvalCallback):
        """EvalCallback that evaluates on the same episodes every time (the eval env is re-seeded, so the learning
        curve shows the policy changing, not the episodes) and keeps earlier evaluations when a run is resumed."""

        def _on_step(self) -> bool:
            if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
                self.eval_env.seed(seed + EVAL_SEED_OFFSET)
            return super()._on_step()

        def _init_callback(self) -> None:
            super()._init_callback()
            log = Path(self.log_path + ".npz") if self.log_path else None
            if resumed and log is not None and log.is_file():
                with np.load(log) as old:
                    keep = old["timesteps"] <= self.model.num_timesteps
                    self.evaluations_timesteps = [int(t) for t in old["timesteps"][keep]]
                    self.evaluations_results = [list(r) for r in old["results"][keep]]
                    self.evaluations_length = [list(r) for r in old["ep_lengths"][keep]]
                    if "successes" in old.files:
                        self.evaluations_successes = [list(r) for r in old["successes"][keep]]

    class AtomicCheckpointCallback(BaseCallback):
        """Checkpoint model, normalisation statistics and (SAC) replay buffer every `every` steps, atomically."""

        def __init__(self, every: int, keep: int):
            super().__init__()
            self.every, self.keep, self.last = every, keep, 0

        def _on_training_start(self) -> None:
            self.last = self.model.num_timesteps

        def _on_step(self) -> bool:
            if self.model.num_timesteps - self.last >= self.every:
                self.last = self.model.num_timesteps
                save_checkpoint(run_dir, self.model, self.model.get_vec_normalize_env(), keep=self.keep)
            return True

    eval_env = make_vec_env(cfg, 1, seed + EVAL_SEED_OFFSET, monitor_dir=None)
    if cfg.normalize is not None:
        from stable_baselines3.common.vec_env import VecNormalize

        eval_env = VecNormalize(eval_env, training=False, norm_reward=False,
                                **{k: v for k, v in cfg.normalize.items() if k not in ("norm_reward",)})
    every = min(cfg.eval_freq, max(cfg.n_timesteps // 2, 1))  # a short run still gets a learning curve
    evaluator = HistoryEvalCallback(eval_env, n_eval_episodes=cfg.n_eval_episodes,
                                    eval_freq=max(every // n_envs, 1),
                                    log_path=str(run_dir / "eval"), best_model_save_path=str(run_dir / "eval"),
                                    deterministic=True, verbose=0)
    return [evaluator, AtomicCheckpointCallback(cfg.checkpoint_freq, cfg.keep_checkpoints)], eval_env


def train(task: str, algo: str, out: str | Path, config: str | Path | None = None, timesteps: int | None = None,
          seed: int = 0, n_envs: int | None = None, resume: bool = False, progress: bool = True,
          argv: list[str] | None = None, torch_threads: int = 1, log=print) -> Path:
    """Train (or resume) one run; returns the run directory. Raises ConfigError / RunDirError on bad input."""
    run_dir = Path(out)
    env_id = task_id(task)
    command = "vswrist train " + shlex.join(argv) if argv is not None else None
    limit_threads(torch_threads)
    if resume:
        if config is not None:
            raise ConfigError("--config cannot be combined with --resume: a resumed run keeps its config.yaml")
        cfg, seed = read_config(run_dir)
        if cfg.env_id != env_id or cfg.algo != algo:
            raise RunDirError(f"{run_dir} holds a {cfg.algo.upper()} run on {cfg.env_id}, "
                              f"not {algo.upper()} on {env_id}")
        cfg = override(cfg, n_timesteps=timesteps, n_envs=n_envs)
        checkpoint = latest_checkpoint(run_dir)
    else:
        if (run_dir / "config.yaml").exists():
            raise RunDirError(f"{run_dir} already holds a run; continue it with --resume or choose another --out")
        cfg = override(load_config(algo, env_id, config), n_timesteps=timesteps, n_envs=n_envs)
        checkpoint = None
        check_env_kwargs(cfg.env_id, cfg.env_kwargs)
        run_dir.mkdir(parents=True, exist_ok=True)
    write_config(run_dir, cfg, seed)
    update_run_json(run_dir, seed=seed, versions=versions(), status="running",
                    **({"command": command} if command else {}))

    venv = make_vec_env(cfg, cfg.n_envs, seed, monitor_dir=run_dir / "monitor",
                        prefix=f"train_{int(time.time())}")
    model = None
    try:
        if checkpoint is not None:
            if cfg.normalize is not None:
                venv = load_vecnormalize(checkpoint / "vecnormalize.pkl", venv)
                venv.training = True
            model = load_model(checkpoint / "model.zip", algo, env=venv)
            model.tensorboard_log = str(run_dir / "tb")
            if (checkpoint / "replay_buffer.pkl").is_file():
                model.load_replay_buffer(checkpoint / "replay_buffer.pkl")
            log(f"resuming {run_dir} from {checkpoint.name} ({model.num_timesteps} of {cfg.n_timesteps} steps)")
        else:
            if resume:
                log(f"no checkpoint in {run_dir}: starting from scratch")
            venv = wrap_normalize(venv, cfg)
            from vswrist_gym.agents.hparams import algo_class

            model = algo_class(algo)(cfg.policy, venv, seed=seed, tensorboard_log=str(run_dir / "tb"),
                                     policy_kwargs=cfg.policy_kwargs or None, device="cpu", verbose=0,
                                     **cfg.algo_kwargs)
        remaining = cfg.n_timesteps - model.num_timesteps
        if remaining <= 0:
            log(f"{run_dir}: already trained for {model.num_timesteps} steps (>= {cfg.n_timesteps})")
        else:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
                callbacks, eval_env = _callbacks(run_dir, cfg, cfg.n_envs, seed, resumed=checkpoint is not None)
            start = time.time()
            try:
                model.learn(total_timesteps=remaining, callback=callbacks, progress_bar=progress,
                            reset_num_timesteps=checkpoint is None, tb_log_name=algo)
            except KeyboardInterrupt:
                save_checkpoint(run_dir, model, model.get_vec_normalize_env(), keep=cfg.keep_checkpoints)
                update_run_json(run_dir, status="interrupted", num_timesteps=int(model.num_timesteps))
                log(f"interrupted at {model.num_timesteps} steps; checkpoint saved, continue with --resume")
                raise
            except Exception as exc:  # noqa: BLE001 - an environment or worker failure: keep what was learnt
                update_run_json(run_dir, status="failed", error=f"{type(exc).__name__}: {exc}",
                                num_timesteps=int(model.num_timesteps))
                latest = latest_checkpoint(run_dir)
                what = (f"{type(exc).__name__}: {exc}" if not isinstance(exc, (EOFError, ConnectionError))
                        else "a SubprocVecEnv worker died (its traceback is printed above)")
                hint = f"; the last checkpoint ({latest.name}) is intact, continue with --resume" if latest else ""
                raise TrainingError(
                    f"training stopped at step {model.num_timesteps} of {cfg.n_timesteps}: {what}{hint}") from exc
            finally:
                try:
                    eval_env.close()
                except (EOFError, OSError):
                    pass
            update_run_json(run_dir, train_seconds=round(time.time() - start, 1))
        save_checkpoint(run_dir, model, model.get_vec_normalize_env(), keep=cfg.keep_checkpoints)
        atomic_write_bytes(run_dir / "model.zip", model_bytes(model))
        vn = model.get_vec_normalize_env()
        if vn is not None:
            import pickle

            atomic_write_bytes(run_dir / "vecnormalize.pkl", pickle.dumps(vn))
        update_run_json(run_dir, status="finished", num_timesteps=int(model.num_timesteps))
    finally:
        try:
            venv.close()
        except (EOFError, OSError):  # workers already gone (Ctrl-C reaches the whole process group)
            pass
    return run_dir


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vswrist train", description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("--task", required=True, help="task id (VSWrist/LoadHold-v0) or short name (LoadHold)")
    p.add_argument("--algo", required=True, choices=ALGO_NAMES)
    p.add_argument("--config", help="hyperparameter YAML keyed by env id (default: the packaged configs/<algo>.yaml)")
    p.add_argument("--timesteps", type=int, help="total training steps (overrides n_timesteps)")
    p.add_argument("--seed", type=int, default=0, help="seed of the model and of the training environments")
    p.add_argument("--n-envs", type=int, help="parallel environments (overrides n_envs)")
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last checkpoint")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--torch-threads", type=int, default=1, help="torch threads in the learner process (default 1)")
    return p


def _positive(name: str, value: int | None) -> None:
    if value is not None and value <= 0:
        raise ConfigError(f"{name} must be a positive integer, got {value}")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    try:
        _positive("--timesteps", args.timesteps)
        _positive("--n-envs", args.n_envs)
        _positive("--torch-threads", args.torch_threads)
        run_dir = train(args.task, args.algo, args.out, config=args.config, timesteps=args.timesteps,
                        seed=args.seed, n_envs=args.n_envs, resume=args.resume, progress=not args.no_progress,
                        argv=argv, torch_threads=args.torch_threads)
    except (ConfigError, RunDirError) as exc:
        print(f"vswrist train: error: {exc}", file=sys.stderr)
        return 2
    except TrainingError as exc:
        print(f"vswrist train: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    print(f"run directory: {run_dir}  (TensorBoard: tensorboard --logdir {run_dir / 'tb'})")
    return 0
