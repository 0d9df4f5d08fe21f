"""Checkpoints: written completely under a temporary name, renamed into place, then named by latest.json; read
back newest first, falling back to the newest intact one; no pickle read from them but SB3's model file."""

from __future__ import annotations

import io
import json
import logging
import os
import shutil
import tempfile
import time
from pathlib import Path

from vswrist_gym.agents.env_factory import wrap_frame_stack
from vswrist_gym.agents.fileio import RunDirError, atomic_write_text
from vswrist_gym.agents.hparams import algo_class
from vswrist_gym.agents.run_stats import (REPLAY_FILE, VECNORM_FILE, VECNORM_LEGACY_FILE, load_replay_buffer,
                                          load_vecnormalize, save_replay_buffer, save_vecnormalize)

logger = logging.getLogger(__name__)


def model_bytes(model) -> bytes:
    buf = io.BytesIO()
    model.save(buf)
    return buf.getvalue()


def load_model(path: Path, algo: str, env=None, device: str = "cpu"):
    """Load an SB3 model, turning a missing or unreadable file into a RunDirError that says what to do."""
    path = Path(path)
    if not path.is_file():
        raise RunDirError(f"model file not found: {path}")
    try:
        return algo_class(algo).load(path, env=env, device=device)
    except Exception as exc:  # noqa: BLE001 - zip, pickle, torch and key errors all mean "unreadable"
        raise RunDirError(f"model file {path} is corrupted or not a {algo.upper()} model "
                          f"({type(exc).__name__}: {exc})") from None


def save_checkpoint(run_dir: Path, model, vecnorm, keep: int = 2, with_replay_buffer: bool = True) -> Path:
    """Write checkpoints/step_<N>/ completely under a temporary name, rename it, then point latest.json at it."""
    from stable_baselines3.common.buffers import ReplayBuffer

    ck_root = Path(run_dir) / "checkpoints"
    ck_root.mkdir(parents=True, exist_ok=True)
    step = int(model.num_timesteps)
    final = ck_root / f"step_{step:010d}"
    tmp = Path(tempfile.mkdtemp(prefix=".tmp_step_", dir=ck_root))
    try:
        (tmp / "model.zip").write_bytes(model_bytes(model))
        if vecnorm is not None:
            save_vecnormalize(tmp / VECNORM_FILE, vecnorm)
        buffer = getattr(model, "replay_buffer", None)
        # other buffer classes (HER, dict observations) have no plain-array form and are not saved: SB3's own
        # format is a pickle, which vswrist never reads back; such a run resumes with an empty buffer
        if with_replay_buffer and type(buffer) is ReplayBuffer:
            save_replay_buffer(tmp / REPLAY_FILE, buffer)
        if final.exists():
            shutil.rmtree(final)
        os.rename(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    atomic_write_text(ck_root / "latest.json", json.dumps({"step": step, "dir": final.name, "time": time.time()}))
    complete = sorted(p for p in ck_root.glob("step_*") if p.is_dir())
    for old in complete[:-keep]:
        if old != final:
            shutil.rmtree(old, ignore_errors=True)
    return final


def checkpoints(run_dir: Path) -> list[Path]:
    """Complete checkpoints (renamed into place, with a model file), newest first."""
    ck_root = Path(run_dir) / "checkpoints"
    return sorted((p for p in ck_root.glob("step_*") if (p / "model.zip").is_file()), reverse=True)


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The checkpoint latest.json names; if that is unreadable, the newest complete step_* folder."""
    ck_root = Path(run_dir) / "checkpoints"
    try:
        doc = json.loads((ck_root / "latest.json").read_text())
        path = ck_root / doc["dir"]
        if (path / "model.zip").is_file():
            return path
    except (OSError, ValueError, KeyError, TypeError):
        pass
    complete = checkpoints(run_dir)
    return complete[0] if complete else None


def checkpoint_step(folder: Path | None) -> int | None:
    """The training step of a checkpoint folder step_<N> (None for no folder or another name)."""
    try:
        return int(folder.name.split("_", 1)[1]) if folder is not None and folder.name.startswith("step_") else None
    except ValueError:
        return None


def final_model_step(run_dir: Path) -> int | None:
    """The training step of the run's top-level model.zip, from run.json: `final_model_step` (written with it)
    or, for runs written before that field, the step of the last 'finished' invocation; None when unknown."""
    try:
        doc = json.loads((Path(run_dir) / "run.json").read_text())
    except (OSError, ValueError):
        return None
    if isinstance(doc.get("final_model_step"), int):
        return doc["final_model_step"]
    finished = [h for h in doc.get("history", []) if isinstance(h, dict) and h.get("status") == "finished"]
    step = finished[-1].get("reached_step") if finished else None
    return int(step) if isinstance(step, (int, float)) else None


def load_checkpoint(checkpoint: Path, algo: str, venv, normalize: bool, frame_stack: int = 1):
    """Model (with its normalisation and frame-stacking wrappers around `venv` and its replay buffer) from one
    checkpoint folder. Raises RunDirError naming the file when any part of it does not read back."""
    env = venv
    if normalize:
        env = load_vecnormalize(checkpoint, venv)
        env.training = True
    env = wrap_frame_stack(env, frame_stack)
    refuse_pickles(checkpoint)
    model = load_model(checkpoint / "model.zip", algo, env=env)
    if getattr(model, "replay_buffer", None) is not None and (checkpoint / REPLAY_FILE).is_file():
        load_replay_buffer(checkpoint / REPLAY_FILE, model.replay_buffer)
    return model, env


def refuse_pickles(run_dir: Path) -> None:
    """A replay buffer (or any file but normalisation statistics) saved as a pickle under `run_dir` is refused
    unread: unpickling can run any code, and vswrist writes replay buffers as plain arrays only."""
    found = sorted(p for p in Path(run_dir).rglob("*.pkl") if p.name != VECNORM_LEGACY_FILE)
    if found:
        more = f" (and {len(found) - 1} more)" if len(found) > 1 else ""
        raise RunDirError(f"{found[0]}{more}: a pickle file, which vswrist never loads (unpickling can run any "
                          f"code; replay buffers are saved as {REPLAY_FILE}); delete it to go on, a resumed run "
                          f"then continues with an empty replay buffer")


def load_newest_intact(run_dir: Path, algo: str, venv, normalize: bool, log=None, frame_stack: int = 1):
    """(checkpoint, model, env) from the newest checkpoint that reads back completely; older ones are tried when
    the newest is damaged (truncated file, missing statistics), and the fallback is reported in one line.
    (None, None, venv) when the run has no checkpoint; RunDirError when none is intact."""
    log = log or logger.warning
    refuse_pickles(run_dir)
    found = checkpoints(run_dir)
    latest = latest_checkpoint(run_dir)
    if latest is not None and latest in found:  # latest.json first, then the others newest first
        found = [latest] + [c for c in found if c != latest]
    if (Path(run_dir) / "model.zip").is_file():  # the final model last: it has no replay buffer
        found.append(Path(run_dir))
    damaged = []
    for ck in found:
        try:
            model, env = load_checkpoint(ck, algo, venv, normalize, frame_stack)
        except RunDirError as exc:
            damaged.append(f"{ck.name}: {exc}")
            continue
        if damaged:
            what = ck.name if ck != Path(run_dir) else "the run's final model.zip"
            log(f"checkpoint {damaged[0]}; resuming from the newest intact one, {what}")
        if getattr(model, "replay_buffer", None) is not None and not any(
                (ck / name).is_file() for name in (REPLAY_FILE,)):
            log(f"{ck / 'model.zip'} has no replay buffer beside it: training continues with an empty one")
        return ck, model, env
    if damaged:
        raise RunDirError(f"no intact checkpoint in {Path(run_dir) / 'checkpoints'}: " + "; ".join(damaged)
                          + " (start a new run with another --out)")
    return None, None, venv
