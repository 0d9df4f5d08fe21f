"""Bad input and broken files never cost work: one-line errors before anything is built, no half-made runs,
partial evaluation results, fallback to the newest intact checkpoint, killed runs recognised, and normalisation
statistics that load without executing anything. Tiny budgets on Pendulum-v1 (no VS-Wrist simulator needed)."""

from __future__ import annotations

import errno
import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from vswrist_gym.agents import compare as compare_mod
from vswrist_gym.agents import evaluate as evaluate_mod
from vswrist_gym.agents import protocol, runs
from vswrist_gym.agents import train as train_mod
from vswrist_gym.agents.hparams import ConfigError

TASK = "Pendulum-v1"
TINY_SAC = {"n_timesteps": 600, "n_envs": 1, "vec_env": "dummy", "normalize": {"norm_obs": True, "norm_reward": True},
            "eval_freq": 300, "n_eval_episodes": 1, "checkpoint_freq": 200, "keep_checkpoints": 2,
            "buffer_size": 5000, "learning_starts": 100, "batch_size": 32, "policy_kwargs": {"net_arch": [16]}}


def vswrist(*args, timeout=300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    return subprocess.run([sys.executable, "-m", "vswrist_gym.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=env)


def one_line_error(res: subprocess.CompletedProcess, command: str) -> str:
    """The command failed with exit code 2 and exactly one line on stderr, in the `vswrist CMD: error:` form."""
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"vswrist {command}: error: "), res.stderr
    return lines[0]


@pytest.fixture(scope="module")
def sac_config(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cfg") / "sac.yaml"
    path.write_text(yaml.safe_dump({TASK: TINY_SAC}))
    return path


@pytest.fixture(scope="module")
def sac_run(tmp_path_factory, sac_config) -> Path:
    """A finished tiny SAC run with VecNormalize: checkpoints at steps 480 and 600 (keep 2): every
    min(checkpoint_freq 200, budget 600 / 5) = 120 steps."""
    out = tmp_path_factory.mktemp("sac") / "run"
    train_mod.train(TASK, "sac", out, config=sac_config, seed=1, progress=False, log=lambda *_: None)
    return out


def _tree(path: Path) -> dict:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------------------------------- bad input, up front


@pytest.mark.parametrize("seed", ["-1", str(2**32)])
def test_seed_out_of_range_is_one_line_and_creates_nothing(tmp_path, seed):
    out = tmp_path / "run"
    line = one_line_error(vswrist("train", "--task", TASK, "--algo", "sac", "--seed", seed, "--out", out), "train")
    assert "--seed" in line and "4294967295" in line and seed in line
    assert not out.exists()
    line = one_line_error(vswrist("compare", "--task", "LoadHold", "--seeds", "0", seed, "--out", tmp_path / "cmp"),
                          "compare")
    assert "--seeds" in line and "4294967295" in line
    assert not (tmp_path / "cmp").exists()


def test_seed_is_checked_before_any_environment_is_built(tmp_path, monkeypatch):
    def built(*_a, **_k):
        raise AssertionError("an environment was built before the seed was checked")

    monkeypatch.setattr(train_mod, "make_vec_env", built)
    monkeypatch.setattr(train_mod, "check_env_kwargs", built)
    with pytest.raises(ConfigError, match=r"\[0, 2\*\*32 - 1"):
        train_mod.train(TASK, "sac", tmp_path / "run", seed=-1, progress=False)
    assert not (tmp_path / "run").exists()


def test_out_under_a_file_is_one_line(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    line = one_line_error(vswrist("train", "--task", TASK, "--algo", "ppo", "--out", blocker / "run"), "train")
    assert str(blocker) in line and "is a file" in line
    line = one_line_error(vswrist("train", "--task", TASK, "--algo", "ppo", "--out", blocker), "train")
    assert "is a file" in line
    line = one_line_error(vswrist("evaluate", "--task", "LoadHold", "--agent", "analytic", "--episodes", "1",
                                  "--seeds", "0", "--out", blocker / "eval"), "evaluate")
    assert "is a file" in line
    line = one_line_error(vswrist("compare", "--task", "LoadHold", "--seeds", "0", "--out", blocker / "cmp"),
                          "compare")
    assert "is a file" in line
    assert blocker.read_text() == "not a folder"


def test_out_where_even_root_cannot_write(tmp_path):
    """sysfs admits no new files, for root neither: a real (not simulated) unwritable folder on Linux."""
    target = Path("/sys/vswrist_gym_probe/run")
    try:
        fd, probe = tempfile.mkstemp(dir="/sys")
        os.close(fd)
        os.unlink(probe)
        pytest.skip("/sys accepts new files on this machine")
    except OSError:
        pass
    line = one_line_error(vswrist("train", "--task", TASK, "--algo", "ppo", "--out", target), "train")
    assert "not writable" in line and "/sys" in line
    line = one_line_error(vswrist("evaluate", "--task", "LoadHold", "--agent", "analytic", "--episodes", "1",
                                  "--seeds", "0", "--out", target), "evaluate")
    assert "not writable" in line


def test_read_only_out_is_refused_before_anything_is_built(tmp_path, monkeypatch):
    """A read-only mount, simulated (root writes through chmod 555, and no read-only mount is available to a
    test): the probe file's creation fails with EROFS, as it does on such a mount."""
    def read_only(*_a, **_k):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    def built(*_a, **_k):
        raise AssertionError("an environment was built before --out was checked")

    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    monkeypatch.setattr(train_mod, "make_vec_env", built)
    monkeypatch.setattr(train_mod, "check_env_kwargs", built)
    with pytest.raises(runs.RunDirError, match="not writable.*[Rr]ead-only"):
        train_mod.train(TASK, "ppo", tmp_path / "run", progress=False)
    with pytest.raises(runs.RunDirError, match="not writable"):
        evaluate_mod.run("LoadHold", "analytic", 1, [0], tmp_path / "eval")
    assert list(tmp_path.iterdir()) == []


def test_non_empty_folder_that_is_not_a_run_is_refused(tmp_path):
    folder = tmp_path / "my_notes"
    folder.mkdir()
    (folder / "thesis.tex").write_text("precious")
    before = _tree(folder)
    line = one_line_error(vswrist("train", "--task", TASK, "--algo", "ppo", "--out", folder), "train")
    assert str(folder) in line and "config.yaml" in line and "thesis.tex" in line
    line = one_line_error(vswrist("evaluate", "--task", "LoadHold", "--agent", "analytic", "--episodes", "1",
                                  "--seeds", "0", "--out", folder), "evaluate")
    assert "thesis.tex" in line
    line = one_line_error(vswrist("compare", "--task", "LoadHold", "--seeds", "0", "--out", folder), "compare")
    assert "thesis.tex" in line
    assert _tree(folder) == before
    # --retrain deletes runs only: a folder of the run's name that is not a run is refused, not deleted
    (tmp_path / "runs" / "ppo_seed0").mkdir(parents=True)
    (tmp_path / "runs" / "ppo_seed0" / "data.csv").write_text("1,2,3")
    line = one_line_error(vswrist("compare", "--task", "LoadHold", "--algos", "ppo", "--seeds", "0", "--retrain",
                                  "--out", tmp_path / "cmp", "--runs-dir", tmp_path / "runs"), "compare")
    assert "data.csv" in line and (tmp_path / "runs" / "ppo_seed0" / "data.csv").read_text() == "1,2,3"


def test_a_failed_start_leaves_no_half_made_run(tmp_path, sac_config, monkeypatch):
    """Whatever fails between creating the run directory and the first training step, nothing is left: new
    folders are removed, a folder that existed empty is emptied, so the same --out works next time."""
    def broken(*_a, **_k):
        raise RuntimeError("worker failed to start (simulated)")

    monkeypatch.setattr(train_mod, "make_vec_env", broken)
    nested = tmp_path / "new" / "deeper" / "run"
    with pytest.raises(RuntimeError, match="simulated"):
        train_mod.train(TASK, "sac", nested, config=sac_config, progress=False)
    assert not (tmp_path / "new").exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(RuntimeError, match="simulated"):
        train_mod.train(TASK, "sac", empty, config=sac_config, progress=False)
    assert empty.is_dir() and list(empty.iterdir()) == []
    monkeypatch.undo()
    cfg = tmp_path / "short.yaml"
    cfg.write_text(yaml.safe_dump({TASK: {**TINY_SAC, "n_timesteps": 150}}))
    train_mod.train(TASK, "sac", empty, config=cfg, progress=False, log=lambda *_: None)
    assert json.loads((empty / "run.json").read_text())["status"] == "finished"


# ------------------------------------------------------------------------------------------- evaluation results


def test_evaluate_keeps_finished_episodes_when_it_fails(tmp_path, monkeypatch):
    """An episode that fails after two have finished: both are on disk, identical to a full evaluation's
    (episode after episode in one env; the batched path keeps whole seeds, next test)."""
    monkeypatch.setattr(protocol, "BATCH_EPISODES", False)
    full = evaluate_mod.run("LoadHold", "analytic:0.5", 3, [0], tmp_path / "full")
    assert not (tmp_path / "full" / protocol.PARTIAL_FILE).exists()
    original, calls = protocol.run_episode, []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            raise RuntimeError("simulation diverged (simulated)")
        return original(*args, **kwargs)

    monkeypatch.setattr(protocol, "run_episode", failing)
    with pytest.raises(RuntimeError, match="simulated"):
        evaluate_mod.run("LoadHold", "analytic:0.5", 3, [0], tmp_path / "broken")
    header, records = protocol.read_partial(tmp_path / "broken" / protocol.PARTIAL_FILE)
    assert header["agent"] == full["agent"] and len(records) == 2
    done = json.loads((tmp_path / "full" / "metrics.json").read_text())["episodes"]
    assert [r["return"] for r in records] == [r["return"] for r in done[:2]]
    assert not (tmp_path / "broken" / "metrics.json").exists()
    # the same --out may be used again (it holds only evaluation files), and the rerun completes it
    monkeypatch.undo()
    monkeypatch.setattr(protocol, "BATCH_EPISODES", False)
    evaluate_mod.run("LoadHold", "analytic:0.5", 3, [0], tmp_path / "broken")
    assert not (tmp_path / "broken" / protocol.PARTIAL_FILE).exists()



def test_batched_evaluate_keeps_finished_seeds_when_it_fails(tmp_path, monkeypatch):
    """The batched path (a seed's episodes as one batch) fails on the second seed: the first seed's episodes
    are on disk, identical to a full evaluation's."""
    full = evaluate_mod.run("LoadHold", "analytic:0.5", 2, [0, 1], tmp_path / "full")
    original, calls = protocol.run_episodes_batched, []

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("simulation diverged (simulated)")
        return original(*args, **kwargs)

    monkeypatch.setattr(protocol, "run_episodes_batched", failing)
    with pytest.raises(RuntimeError, match="simulated"):
        evaluate_mod.run("LoadHold", "analytic:0.5", 2, [0, 1], tmp_path / "broken")
    _, records = protocol.read_partial(tmp_path / "broken" / protocol.PARTIAL_FILE)
    done = json.loads((tmp_path / "full" / "metrics.json").read_text())["episodes"]
    assert len(calls) == 2 and [r["return"] for r in records] == [r["return"] for r in done[:2]]

def test_evaluate_killed_outright_keeps_finished_episodes(tmp_path):
    """SIGKILL during an evaluation: the partial file reads back whole, with every episode finished before."""
    out = tmp_path / "eval"
    env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    proc = subprocess.Popen([sys.executable, "-m", "vswrist_gym.cli", "evaluate", "--task", "LoadHold", "--agent",
                             "analytic:0.5", "--episodes", "200", "--seeds", "0", "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    partial = out / protocol.PARTIAL_FILE

    def two_done():
        try:
            return len(protocol.read_partial(partial)[1]) >= 2
        except (OSError, ValueError, IndexError):
            return False

    try:
        assert _wait_for(two_done), "no episode finished within the time limit"
        proc.kill()
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    header, records = protocol.read_partial(partial)  # whole lines only: every rewrite is atomic
    assert header["agent"] == "analytic:+0.50" and len(records) >= 2
    assert [r["episode"] for r in records] == list(range(len(records)))
    assert not (out / "metrics.json").exists()


# ------------------------------------------------------------------------------------------- recovery


@pytest.mark.parametrize("damage", ["model.zip", "vecnormalize.npz", "replay_buffer.npz"])
def test_resume_falls_back_to_the_newest_intact_checkpoint(sac_run, tmp_path, damage):
    run = tmp_path / "run"
    shutil.copytree(sac_run, run)
    found = runs.checkpoints(run)
    assert [c.name for c in found] == ["step_0000000600", "step_0000000480"]
    newest = found[0] / damage
    newest.write_bytes(newest.read_bytes()[: newest.stat().st_size // 2])  # truncated, as by a full disk
    logs = []
    train_mod.train(TASK, "sac", run, timesteps=800, resume=True, progress=False, log=logs.append)
    said = [m for m in logs if "intact" in m]
    assert len(said) == 1 and damage in said[0] and "step_0000000480" in said[0], logs
    assert any("resuming" in m and "480 of 800" in m for m in logs), logs
    doc = json.loads((run / "run.json").read_text())
    assert doc["status"] == "finished" and doc["num_timesteps"] == 800


def test_resume_with_no_intact_checkpoint_says_so_and_changes_nothing(sac_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(sac_run, run)
    for ck in runs.checkpoints(run):
        (ck / "model.zip").write_bytes(b"PK\x03\x04 truncated")
    # the final model is the last resort: no replay buffer beside it, and the resume says so
    final = tmp_path / "final"
    shutil.copytree(run, final)
    logs = []
    train_mod.train(TASK, "sac", final, timesteps=800, resume=True, progress=False, log=logs.append)
    assert any("final model.zip (600 of 800" in m for m in logs) and any("empty one" in m for m in logs), logs
    (run / "model.zip").write_bytes(b"PK\x03\x04 truncated")
    before = _tree(run)
    with pytest.raises(runs.RunDirError, match="no intact checkpoint.*step_0000000600.*step_0000000480"):
        train_mod.train(TASK, "sac", run, timesteps=800, resume=True, progress=False, log=lambda *_: None)
    assert _tree(run) == before


def _wait_for(predicate, timeout=180.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if predicate():
            return True
        time.sleep(0.2)
    return False


def test_a_killed_run_is_marked_on_resume(tmp_path, sac_config):
    """SIGKILL (no handler runs): run.json still says "running"; the resume notices the process is gone, records
    "killed" with the step it reached in run.json's history, says so, and continues from the checkpoint."""
    cfg = tmp_path / "long.yaml"
    cfg.write_text(yaml.safe_dump({TASK: {**TINY_SAC, "n_timesteps": 1_000_000, "eval_freq": 100_000}}))
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    proc = subprocess.Popen([sys.executable, "-m", "vswrist_gym.cli", "train", "--task", TASK, "--algo", "sac",
                             "--config", str(cfg), "--out", str(out), "--no-progress"], start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    try:
        assert _wait_for(lambda: runs.latest_checkpoint(out) is not None), "no checkpoint within the time limit"
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    doc = json.loads((out / "run.json").read_text())
    assert doc["status"] == "running" and doc["process"]["pid"] == proc.pid
    step = int(runs.latest_checkpoint(out).name.split("_")[1])
    logs = []
    train_mod.train(TASK, "sac", out, timesteps=step + 200, resume=True, progress=False, log=logs.append)
    assert any("killed" in m and str(proc.pid) in m for m in logs), logs
    doc = json.loads((out / "run.json").read_text())
    killed = [h for h in doc["history"] if h["status"] == "killed"]
    assert len(killed) == 1 and killed[0]["pid"] == proc.pid and killed[0]["reached_step"] >= step
    assert doc["status"] == "finished" and doc["num_timesteps"] == step + 200


def test_a_live_training_process_is_not_taken_for_killed(sac_run, tmp_path):
    """A run.json naming a process that still runs: resuming is refused (two trainings would write the same
    checkpoints). The same pid with another start time is a recycled pid: that run was killed."""
    run = tmp_path / "run"
    shutil.copytree(sac_run, run)
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        record = {"pid": other.pid, "host": runs.this_process()["host"],
                  "proc_start": runs._proc_start_ticks(other.pid)}
        runs.update_run_json(run, status="running", process=record)
        with pytest.raises(runs.RunDirError, match=f"being trained by process {other.pid}"):
            train_mod.train(TASK, "sac", run, timesteps=800, resume=True, progress=False)
        if record["proc_start"] is not None:  # Linux: the start time tells a recycled pid apart
            assert runs.process_alive({**record, "proc_start": record["proc_start"] + 1}) is False
    finally:
        other.kill()
        other.wait()
    assert runs.process_alive(record) is False
    assert runs.process_alive({**record, "host": "another-machine"}) is None


# ------------------------------------------------------------------------------------------- safe loading


def _stepped_vecnormalize():
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(DummyVecEnv([lambda: gym.make(TASK), lambda: gym.make(TASK)]), gamma=0.9, clip_obs=7.0,
                        clip_reward=3.0, epsilon=1e-6)
    venv.seed(0)
    venv.reset()
    rng = np.random.default_rng(0)
    for _ in range(50):
        venv.step(rng.uniform(-2, 2, size=(2, 1)).astype(np.float32))
    return venv


def test_vecnormalize_round_trip_through_plain_arrays(tmp_path):
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv

    vn = _stepped_vecnormalize()
    path = tmp_path / runs.VECNORM_FILE
    runs.save_vecnormalize(path, vn)
    with np.load(path, allow_pickle=False) as a:  # plain arrays: loads without pickle
        assert {"obs_mean", "obs_var", "obs_count", "ret_mean", "ret_var", "gamma", "epsilon"} <= set(a.files)
    back = runs.load_vecnormalize(path, None)
    for name in ("obs_rms", "ret_rms"):
        a, b = getattr(vn, name), getattr(back, name)
        assert np.array_equal(a.mean, b.mean) and np.array_equal(a.var, b.var) and a.count == b.count
    for attr in ("clip_obs", "clip_reward", "gamma", "epsilon", "norm_obs", "norm_reward", "training"):
        assert getattr(back, attr) == getattr(vn, attr), attr
    obs = np.random.default_rng(1).normal(size=(5, 3)).astype(np.float32)
    assert np.array_equal(back.normalize_obs(obs), vn.normalize_obs(obs))
    # wrapped around a fresh environment it steps like any VecNormalize
    wrapped = runs.load_vecnormalize(tmp_path, DummyVecEnv([lambda: gym.make(TASK)]))
    wrapped.reset()
    assert wrapped.step(np.zeros((1, 1), dtype=np.float32))[0].shape == (1, 3)
    # the pickle of an older run reads through the allow-list to the same statistics
    (tmp_path / "legacy").mkdir()
    (tmp_path / "legacy" / runs.VECNORM_LEGACY_FILE).write_bytes(pickle.dumps(vn))
    legacy = runs.load_vecnormalize(tmp_path / "legacy", None)
    assert np.array_equal(legacy.obs_rms.var, vn.obs_rms.var) and legacy.gamma == vn.gamma


class _Evil:
    def __init__(self, sentinel: Path):
        self.sentinel = sentinel

    def __reduce__(self):
        return (exec, (f"open({str(self.sentinel)!r}, 'w').write('pwned')",))


def test_a_malicious_statistics_file_is_not_executed(sac_run, tmp_path):
    sentinel = tmp_path / "executed"
    evil = pickle.dumps(_Evil(sentinel))
    pickle.loads(evil)  # the payload works when unpickled naively ...
    assert sentinel.exists()
    sentinel.unlink()
    folder = tmp_path / "plain"
    folder.mkdir()
    (folder / runs.VECNORM_LEGACY_FILE).write_bytes(evil)
    with pytest.raises(runs.RunDirError, match="builtins.exec"):
        runs.load_vecnormalize(folder, None)
    # ... hidden inside genuine statistics too
    vn = _stepped_vecnormalize()
    vn.venv, vn.class_attributes = None, {}  # what __getstate__ leaves out, so that the rest pickles
    vn.payload = _Evil(sentinel)
    (folder / runs.VECNORM_LEGACY_FILE).write_bytes(pickle.dumps(vn))
    with pytest.raises(runs.RunDirError, match="builtins.exec"):
        runs.load_vecnormalize(folder, None)
    # a shared run directory with such a file: evaluating it refuses, runs nothing
    shared = tmp_path / "shared"
    shutil.copytree(sac_run, shared)
    (shared / runs.VECNORM_FILE).unlink()
    (shared / runs.VECNORM_LEGACY_FILE).write_bytes(evil)
    with pytest.raises(runs.RunDirError, match="not loaded"):
        runs.TrainedAgent(shared)
    # an .npz that smuggles a pickled object array is refused by allow_pickle=False
    np.savez(shared / runs.VECNORM_FILE, obs_mean=np.array([_Evil(sentinel)], dtype=object))
    with pytest.raises(runs.RunDirError, match="corrupted"):
        runs.TrainedAgent(shared)
    assert not sentinel.exists()


def test_replay_buffer_round_trip_and_size(sac_run, tmp_path):
    """The compact buffer holds exactly the filled transitions of SB3's own buffer, in much less space."""
    import io

    model = runs.load_model(sac_run / "model.zip", "sac")
    latest = runs.checkpoints(sac_run)[0]
    runs.load_replay_buffer(latest / runs.REPLAY_FILE, model.replay_buffer)
    buf = model.replay_buffer
    assert buf.pos == 600 and not buf.full  # 600 steps into a 5000-transition buffer
    fresh = runs.load_model(sac_run / "model.zip", "sac")
    runs.save_replay_buffer(tmp_path / "rb.npz", buf)
    runs.load_replay_buffer(tmp_path / "rb.npz", fresh.replay_buffer)
    for name in runs.REPLAY_ARRAYS:
        assert np.array_equal(getattr(fresh.replay_buffer, name), getattr(buf, name)), name
    assert np.any(buf.observations[:600] != 0) and not np.any(buf.observations[600:])
    pickled = io.BytesIO()
    model.save_replay_buffer(pickled)
    assert (tmp_path / "rb.npz").stat().st_size < 0.25 * len(pickled.getvalue())  # 600 of 5000 rows kept


def test_checkpoints_and_final_files_hold_no_pickle_but_the_model(sac_run):
    names = {p.name for p in sac_run.rglob("*") if p.is_file()}
    assert runs.VECNORM_FILE in names and runs.REPLAY_FILE in names
    assert not {n for n in names if n.endswith(".pkl")}


# ------------------------------------------------------------------------------------------- no code from data


def test_a_planted_replay_buffer_pickle_is_refused_unread(sac_run, tmp_path):
    """A `replay_buffer.pkl` in a checkpoint (SB3's pickle format) is never unpickled: `--resume` stops with one
    line naming it before anything is built, the payload does not run, and the run is unchanged."""
    sentinel = tmp_path / "executed"
    run = tmp_path / "run"
    shutil.copytree(sac_run, run)
    latest = runs.latest_checkpoint(run)
    (latest / "replay_buffer.pkl").write_bytes(pickle.dumps(_Evil(sentinel)))
    before = _tree(run)
    line = one_line_error(vswrist("train", "--task", TASK, "--algo", "sac", "--out", run, "--resume", "--timesteps",
                                  800, "--no-progress"), "train")
    assert "replay_buffer.pkl" in line and "never loads" in line
    assert not sentinel.exists() and _tree(run) == before
    with pytest.raises(runs.RunDirError, match="never loads"):
        runs.load_checkpoint(latest, "sac", None, normalize=False)
    assert not sentinel.exists()


# ------------------------------------------------------------------------------------------- lost or stale work


def test_a_short_run_checkpoints_five_times_over_its_budget(tmp_path, monkeypatch):
    """checkpoint_freq as large as the budget: checkpoints still come every budget / 5 steps, and every
    CHECKPOINT_SECONDS of wall time (0 here: at every step)."""
    saved = []
    real = train_mod.save_checkpoint

    def record(run_dir, model, *args, **kwargs):
        saved.append(int(model.num_timesteps))
        return real(run_dir, model, *args, **kwargs)

    monkeypatch.setattr(train_mod, "save_checkpoint", record)
    cfg = tmp_path / "sac.yaml"
    cfg.write_text(yaml.safe_dump({TASK: {**TINY_SAC, "n_timesteps": 500, "checkpoint_freq": 500}}))
    train_mod.train(TASK, "sac", tmp_path / "a", config=cfg, seed=0, progress=False, log=lambda *_: None)
    assert saved == [100, 200, 300, 400, 500, 500]  # the callback's five, then the final save
    saved.clear()
    monkeypatch.setattr(train_mod, "CHECKPOINT_SECONDS", 0.0)
    cfg.write_text(yaml.safe_dump({TASK: {**TINY_SAC, "n_timesteps": 120, "checkpoint_freq": 500,
                                          "learning_starts": 50}}))
    train_mod.train(TASK, "sac", tmp_path / "b", config=cfg, seed=0, progress=False, log=lambda *_: None)
    assert saved[:-1] == list(range(1, 121))


def test_evaluate_takes_the_newest_model_run_json_accounts_for(sac_run, tmp_path):
    """A run extended with --resume and stopped before its new end: model.zip is older than the newest checkpoint.
    The default evaluates the checkpoint and says so; --checkpoint final takes model.zip, with a line."""
    run = tmp_path / "run"
    shutil.copytree(sac_run, run)
    doc = json.loads((run / "run.json").read_text())
    assert doc["final_model_step"] == 600
    newer = run / "checkpoints" / "step_0000000700"
    shutil.copytree(run / "checkpoints" / "step_0000000600", newer)
    (run / "checkpoints" / "latest.json").write_text(json.dumps({"step": 700, "dir": newer.name}))
    agent = runs.TrainedAgent(run)
    assert agent.model_path == newer / "model.zip"
    assert "step 700" in agent.note and "600" in agent.note
    final = runs.TrainedAgent(run, checkpoint="final")
    assert final.model_path == run / "model.zip" and "as asked" in final.note and "700" in final.note
    # a run.json written before final_model_step: the last finished invocation's step stands for model.zip
    del doc["final_model_step"]
    (run / "run.json").write_text(json.dumps(doc))
    assert runs.final_model_step(run) == 600
    assert runs.TrainedAgent(run).model_path == newer / "model.zip"
    # a finished run: model.zip is the newest, and nothing is said
    plain = runs.TrainedAgent(sac_run)
    assert plain.model_path == sac_run / "model.zip" and plain.note is None
    res = vswrist("evaluate", "--task", TASK, "--agent", run, "--episodes", 1, "--seeds", 0, "--out", tmp_path / "ev")
    assert res.returncode == 0, res.stderr
    assert f"model: {newer / 'model.zip'}" in res.stdout  # the result names the model it scored
    assert "newest model run.json accounts for" in res.stderr  # a note: a diagnostic, on stderr
    meta = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert meta["model_file"] == str(newer / "model.zip")
