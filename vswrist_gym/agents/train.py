"""`vswrist train`: train a PPO, SAC or recurrent PPO (ppo_lstm) posture-and-stiffness policy on a task, into a
self-describing run directory.

Example: `vswrist train --task LoadHold --algo ppo --timesteps 50000 --seed 0 --out runs/loadhold_ppo_0`.
The run directory layout is described in `vswrist_gym.agents.runs`; `--resume` continues from its last checkpoint.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shlex
import shutil
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np

from vswrist_gym.agents.hparams import ALGO_NAMES, TRACKS, ConfigError, RunConfig, load_config, track_of, with_track
from vswrist_gym.agents.checkpoints import (latest_checkpoint, load_newest_intact, model_bytes, refuse_pickles,
                                            save_checkpoint)
from vswrist_gym.agents.env_factory import (check_env_id, check_env_kwargs, make_vec_env, wrap_frame_stack,
                                            wrap_normalize)
from vswrist_gym.agents.fileio import RunDirError, atomic_write_bytes, check_new_out, check_writable, created_root
from vswrist_gym.agents.procs import limit_threads, process_alive, steps_done, this_process, versions
from vswrist_gym.agents.run_config import check_seed, override, read_config, update_run_json, write_config
from vswrist_gym.agents.run_stats import VECNORM_FILE, save_vecnormalize
from vswrist_gym.agents.progress import shown as progress_shown

logger = logging.getLogger(__name__)


class TrainingError(RuntimeError):
    """Training stopped because the environment or a worker failed; the run dir keeps its last checkpoint."""


CHECKPOINT_SECONDS = 300.0  # wall time between checkpoints at most: a kill loses minutes, never hours
EVAL_SEED_OFFSET = 10_000  # periodic-evaluation environments never share seeds with the training environments


def task_id(name: str) -> str:
    """Accept a full id ('VSWrist/Polish-v0', 'Pendulum-v1') or a VSWrist short name ('Polish': its newest
    version, 'VSWrist/Polish-v1')."""
    import gymnasium as gym

    import vswrist_gym  # registers the VSWrist/ ids

    if name in gym.registry:
        return name
    if name in vswrist_gym.LATEST:
        return vswrist_gym.LATEST[name]
    if f"VSWrist/{name}" in gym.registry:
        return f"VSWrist/{name}"
    check_env_id(name)  # raises a ConfigError listing the registered tasks
    return name


class _DeferredInterrupt:
    """Ctrl-C while learning stops training at the next environment step (``stop_callback``) instead of raising
    KeyboardInterrupt wherever the signal lands: raised inside a native call or a library's cleanup it can be
    swallowed, and the run then trains on. A second Ctrl-C raises at once. Only in the main thread (a Ray trial
    runs in another; signals are the main thread's)."""

    def __init__(self):
        self.requested = False
        self._previous = None

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handler)
        return self

    def _handler(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __exit__(self, *exc) -> bool:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
        return False

    def stop_callback(self):
        from stable_baselines3.common.callbacks import BaseCallback

        guard = self

        class StopOnInterrupt(BaseCallback):
            def _on_step(self) -> bool:
                return not guard.requested

        return StopOnInterrupt()


def _save_interrupted(run_dir: Path, model, cfg: RunConfig, log) -> None:
    save_checkpoint(run_dir, model, model.get_vec_normalize_env(), keep=cfg.keep_checkpoints)
    update_run_json(run_dir, status="interrupted", num_timesteps=int(model.num_timesteps),
                    checkpoint_step=int(model.num_timesteps),
                    history={"status": "interrupted", "reached_step": int(model.num_timesteps), "time": time.time()})
    log(f"interrupted at {model.num_timesteps} steps; checkpoint saved, continue with --resume")


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
        """Checkpoint model, normalisation statistics and (SAC) replay buffer atomically, every `every` steps or
        `seconds` of wall time, whichever comes first."""

        def __init__(self, every: int, keep: int, seconds: float):
            super().__init__()
            self.every, self.keep, self.seconds, self.last, self.last_time = every, keep, seconds, 0, 0.0

        def _on_training_start(self) -> None:
            self.last, self.last_time = self.model.num_timesteps, time.monotonic()

        def _on_step(self) -> bool:
            steps = self.model.num_timesteps - self.last
            if steps >= self.every or (steps > 0 and time.monotonic() - self.last_time >= self.seconds):
                self.last, self.last_time = self.model.num_timesteps, time.monotonic()
                save_checkpoint(run_dir, self.model, self.model.get_vec_normalize_env(), keep=self.keep)
                update_run_json(run_dir, checkpoint_step=int(self.model.num_timesteps))
            return True

    # with the batched core the periodic evaluation runs its episodes side by side, one world each (world i seeded
    # seed + EVAL_SEED_OFFSET + i, re-seeded before every evaluation), so it costs one episode's worth of Python
    # calls instead of n_eval_episodes; a process-per-env run evaluates on one env, episode after episode
    eval_worlds = cfg.n_eval_episodes if cfg.vec_env == "batch" and cfg.env_id.startswith("VSWrist/") else 1
    eval_env = make_vec_env(cfg, eval_worlds, seed + EVAL_SEED_OFFSET, monitor_dir=None)
    if cfg.normalize is not None:
        from stable_baselines3.common.vec_env import VecNormalize

        eval_env = VecNormalize(eval_env, training=False, norm_reward=False,
                                **{k: v for k, v in cfg.normalize.items() if k not in ("norm_reward",)})
    eval_env = wrap_frame_stack(eval_env, cfg.frame_stack)
    every = min(cfg.eval_freq, max(cfg.n_timesteps // 2, 1))  # a short run still gets a learning curve
    # a short run still gets checkpoints: at least five over its budget, and one every few minutes of wall time
    ck_every = min(cfg.checkpoint_freq, max(cfg.n_timesteps // 5, 1))
    evaluator = HistoryEvalCallback(eval_env, n_eval_episodes=cfg.n_eval_episodes,
                                    eval_freq=max(every // n_envs, 1),
                                    log_path=str(run_dir / "eval"), best_model_save_path=str(run_dir / "eval"),
                                    deterministic=True, verbose=0)
    return [evaluator, AtomicCheckpointCallback(ck_every, cfg.keep_checkpoints, CHECKPOINT_SECONDS)], eval_env


RUN_DIR_MARKER = "config.yaml"  # what makes a folder a run directory (see vswrist_gym.agents.runs)


def check_run_out(run_dir: Path, resume: bool) -> None:
    """`--out` before anything is built: a new run needs a writable folder that is absent or empty (a non-empty
    folder without config.yaml is someone else's); a resumed run needs a writable run directory."""
    if resume:
        if not run_dir.is_dir():
            raise RunDirError(f"--out {run_dir}: run directory not found (nothing to resume)")
        read_config(run_dir)  # a clear error when config.yaml is missing or damaged
        refuse_pickles(run_dir)
        check_writable(run_dir)
        return
    if (run_dir / RUN_DIR_MARKER).exists():
        raise RunDirError(f"{run_dir} already holds a run; continue it with --resume or choose another --out")
    check_new_out(run_dir, allowed=(), what=f"a run directory (one holds {RUN_DIR_MARKER}, written by vswrist train)")


def note_ended_invocation(run_dir: Path, log) -> None:
    """A run.json that still says "running" when a new invocation starts: the process that wrote it either runs
    (refuse: two trainings would write the same checkpoints) or ended without a word (SIGKILL, power loss, out of
    memory), which is recorded in run.json's history with the step it reached, and said."""
    path = run_dir / "run.json"
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return
    if doc.get("status") != "running":
        return
    proc = doc.get("process") or {}
    alive = process_alive(proc)
    if alive and proc.get("pid") == os.getpid():
        alive = False  # an earlier call in this same process (vswrist compare --jobs 1) ended abnormally
    if alive:
        raise RunDirError(f"{run_dir} is being trained by process {proc.get('pid')} on this machine; stop it "
                          f"(Ctrl-C saves a checkpoint) before resuming")
    last = latest_checkpoint(run_dir)
    prefix = doc.get("monitor_prefix")
    reached = int(doc.get("start_step", 0)) + (steps_done(run_dir, prefix) if prefix else 0)
    entry = {"status": "killed", "pid": proc.get("pid"), "host": proc.get("host"),
             "reached_step": max(reached, int(doc.get("checkpoint_step", 0))),
             "checkpoint_step": int(doc.get("checkpoint_step", 0)), "detected": time.time()}
    why = ("ended without a word (killed)" if alive is False else
           f"ran on host {proc.get('host')}, which this machine cannot check; taken as ended without a word")
    update_run_json(run_dir, status="killed", history=entry)
    log(f"{run_dir}: the previous training (process {proc.get('pid')}) {why} after about {entry['reached_step']} "
        f"steps (finished episodes); its last checkpoint is {last.name if last else 'none'}")


def _remove_half_made(run_dir: Path, root: Path | None) -> None:
    """Undo a failed start of a new run: remove the folders this invocation created, or empty `run_dir` when it
    existed (empty) before."""
    if root is not None:
        shutil.rmtree(root, ignore_errors=True)
    elif run_dir.is_dir():
        for child in run_dir.iterdir():
            if child.is_dir() and not child.is_symlink():
                shutil.rmtree(child, ignore_errors=True)
            else:
                child.unlink(missing_ok=True)


def train(task: str, algo: str, out: str | Path, config: str | Path | None = None, timesteps: int | None = None,
          seed: int = 0, n_envs: int | None = None, resume: bool = False, progress: bool = True,
          argv: list[str] | None = None, torch_threads: int = 1, log=None, vec_env: str | None = None,
          track: str | None = None) -> Path:
    """Train (or resume) one run; returns the run directory. Raises ConfigError / RunDirError on bad input,
    before anything is written; a new run that fails to start leaves nothing behind. ``track``: 'stiffness' (the
    policy sets only the stiffness) or 'full' (posture and stiffness); None trains the entry as it is."""
    log = log or logger.info
    run_dir = Path(out)
    seed = check_seed(seed)
    if algo not in ALGO_NAMES:
        raise ConfigError(f"algo must be one of {', '.join(ALGO_NAMES)}, got {algo!r}")
    env_id = task_id(task)
    command = "vswrist train " + shlex.join(argv) if argv is not None else None
    check_run_out(run_dir, resume)
    limit_threads(torch_threads)
    created = None
    if resume:
        if config is not None:
            raise ConfigError("--config cannot be combined with --resume: a resumed run keeps its config.yaml")
        cfg, seed = read_config(run_dir)
        if cfg.env_id != env_id or cfg.algo != algo:
            raise RunDirError(f"{run_dir} holds a {cfg.algo.upper()} run on {cfg.env_id}, "
                              f"not {algo.upper()} on {env_id}")
        if track is not None and track_of(cfg.env_kwargs) != track:
            raise RunDirError(f"{run_dir} is a {track_of(cfg.env_kwargs)}-track run, not {track}")
        cfg = override(cfg, n_timesteps=timesteps, n_envs=n_envs, vec_env=vec_env)
        note_ended_invocation(run_dir, log)
    else:
        cfg = override(with_track(load_config(algo, env_id, config), track), n_timesteps=timesteps, n_envs=n_envs,
                       vec_env=vec_env)
        check_env_kwargs(cfg.env_id, cfg.env_kwargs)
        created = created_root(run_dir)
    prefix = f"train_{int(time.time())}"
    venv = model = checkpoint = None
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        if not resume:
            write_config(run_dir, cfg, seed)  # first: a folder this command writes into is recognisably a run
        venv = make_vec_env(cfg, cfg.n_envs, seed, monitor_dir=run_dir / "monitor", prefix=prefix)
        if resume:
            checkpoint, model, venv = load_newest_intact(run_dir, algo, venv, cfg.normalize is not None, log=log,
                                                          frame_stack=cfg.frame_stack)
        if model is not None:
            model.tensorboard_log = str(run_dir / "tb")
            where = checkpoint.name if checkpoint != run_dir else "its final model.zip"
            log(f"resuming {run_dir} from {where} ({model.num_timesteps} of {cfg.n_timesteps} steps)")
        else:
            if resume:
                log(f"no checkpoint in {run_dir}: starting from scratch")
            venv = wrap_frame_stack(wrap_normalize(venv, cfg), cfg.frame_stack)
            from vswrist_gym.agents.hparams import algo_class

            model = algo_class(algo)(cfg.policy, venv, seed=seed, tensorboard_log=str(run_dir / "tb"),
                                     policy_kwargs=cfg.policy_kwargs or None, device="cpu", verbose=0,
                                     **cfg.algo_kwargs)
        if resume:
            write_config(run_dir, cfg, seed)  # the new budget, once the run is known to continue
        update_run_json(run_dir, seed=seed, versions=versions(), status="running", process=this_process(),
                        start_step=int(model.num_timesteps), monitor_prefix=prefix,
                        **({"command": command} if command else {}))
    except BaseException:
        if venv is not None:
            try:
                venv.close()
            except (EOFError, OSError):
                pass
        if resume:  # the run stays as it was: only this invocation's (empty) episode logs go
            for f in (run_dir / "monitor").glob(f"{prefix}_*"):
                f.unlink(missing_ok=True)
        else:
            _remove_half_made(run_dir, created)
        raise
    try:
        remaining = cfg.n_timesteps - model.num_timesteps
        if remaining <= 0:
            log(f"{run_dir}: already trained for {model.num_timesteps} steps (>= {cfg.n_timesteps})")
        else:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
                callbacks, eval_env = _callbacks(run_dir, cfg, cfg.n_envs, seed, resumed=checkpoint is not None)
            start = time.time()
            guard = _DeferredInterrupt()
            try:
                with guard:
                    model.learn(total_timesteps=remaining, callback=[guard.stop_callback(), *callbacks],
                                # SB3's bar is tqdm.rich, drawn by rich on stdout: only when both streams are a
                                # terminal, so that no bar lands in a file that holds a command's results
                                progress_bar=progress and progress_shown() and sys.stdout.isatty(),
                                reset_num_timesteps=checkpoint is None, tb_log_name=algo)
                if guard.requested:
                    raise KeyboardInterrupt
            except KeyboardInterrupt:
                _save_interrupted(run_dir, model, cfg, log)
                raise
            except Exception as exc:  # noqa: BLE001 - an environment or worker failure: keep what was learnt
                if guard.requested:  # Ctrl-C reached the SubprocVecEnv workers too, and they stopped first
                    _save_interrupted(run_dir, model, cfg, log)
                    raise KeyboardInterrupt from None
                update_run_json(run_dir, status="failed", error=f"{type(exc).__name__}: {exc}",
                                num_timesteps=int(model.num_timesteps),
                                history={"status": "failed", "reached_step": int(model.num_timesteps),
                                         "time": time.time()})
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
            save_vecnormalize(run_dir / VECNORM_FILE, vn)
        update_run_json(run_dir, status="finished", num_timesteps=int(model.num_timesteps),
                        checkpoint_step=int(model.num_timesteps), final_model_step=int(model.num_timesteps),
                        history={"status": "finished", "reached_step": int(model.num_timesteps), "time": time.time()})
    finally:
        try:
            venv.close()
        except (EOFError, OSError):  # workers already gone (Ctrl-C reaches the whole process group)
            pass
    return run_dir


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vswrist train", description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("--task", required=True, help="task id (VSWrist/LoadHold-v0) or short name (LoadHold: its newest version)")
    p.add_argument("--algo", required=True, choices=ALGO_NAMES)
    p.add_argument("--config", help="hyperparameter YAML keyed by env id (default: the packaged configs/<algo>.yaml)")
    p.add_argument("--timesteps", type=int, help="total training steps (overrides n_timesteps)")
    p.add_argument("--seed", type=int, default=0, help="seed of the model and of the training environments")
    p.add_argument("--n-envs", type=int, help="parallel environments (overrides n_envs)")
    p.add_argument("--vec-env", choices=("batch", "subproc", "dummy"),
                   help="how the environments run (overrides vec_env; default batch: one process, physics on "
                        "threads)")
    p.add_argument("--track", choices=TRACKS,
                   help="stiffness: the policy sets only the stiffness (posture reference = the task's); full: "
                        "posture and stiffness (default: as the config entry says)")
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
                        argv=argv, torch_threads=args.torch_threads, vec_env=args.vec_env,
                        track=args.track)
    except (ConfigError, RunDirError) as exc:
        print(f"vswrist train: error: {exc}", file=sys.stderr)
        return 2
    except TrainingError as exc:
        print(f"vswrist train: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # the disk filled or a folder became unwritable while training
        print(f"vswrist train: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    logger.info(f"run directory: {run_dir}  (TensorBoard: tensorboard --logdir {run_dir / 'tb'})")
    return 0
