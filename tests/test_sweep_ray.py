"""`vswrist sweep` on a two-node Ray cluster on this machine (loopback only): the trials' metrics equal serial
`vswrist train` + `vswrist evaluate` runs, a worker node killed mid-trial and a driver killed mid-sweep lose and
duplicate nothing, and a search whose driver is killed resumes without training a finished sample again. Needs
the [sweep] extra; not in the default suite (several minutes):

    python3 -m pytest -m ray tests/test_sweep_ray.py
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.ray
ray = pytest.importorskip("ray")

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONWARNINGS": "ignore::DeprecationWarning"}


@pytest.fixture
def cluster():
    """A head node and one worker node, both on 127.0.0.1; the test adds and removes nodes as it needs."""
    from ray.cluster_utils import Cluster

    made = []

    def make(head_cpus: int, worker_cpus: int):
        c = Cluster(initialize_head=True, head_node_args={"num_cpus": head_cpus, "node_ip_address": "127.0.0.1",
                                                          "include_dashboard": False})
        worker = c.add_node(num_cpus=worker_cpus, node_ip_address="127.0.0.1")
        made.append(c)
        return c, worker

    yield make
    for c in made:
        c.shutdown()


def write_sweep(folder: Path, **fields) -> Path:
    doc = {"mode": "grid", "tasks": ["LoadHold"], "algos": ["ppo"], "seeds": [0, 1], "episodes": 2,
           "stiffness": [0.0], "timesteps": {"ppo": 1024},
           "overrides": {"ppo": {"eval_freq": 512, "checkpoint_freq": 512, "n_eval_episodes": 1}},
           "out": str(folder / "out"), "runs_dir": str(folder / "runs"), **fields}
    path = folder / "sweep.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def start_sweep(path: Path, address: str, *extra, log: Path) -> subprocess.Popen:
    fh = open(log, "a")
    return subprocess.Popen([sys.executable, "-m", "vswrist_gym.cli", "sweep", str(path), "--address", address,
                             *extra], stdout=fh, stderr=subprocess.STDOUT, env=ENV, cwd=path.parent)


def finish(proc: subprocess.Popen, log: Path, timeout: float = 900) -> str:
    proc.wait(timeout=timeout)
    text = log.read_text()
    assert proc.returncode == 0, text[-3000:]
    return text


def cli(*args, cwd) -> None:
    res = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", *map(str, args)], capture_output=True, text=True,
                         env=ENV, cwd=cwd, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]


def episodes(path: Path) -> list[dict]:
    doc = json.loads(path.read_text())
    return [{k: v for k, v in e.items() if k != "agent"} for e in doc["episodes"]]


def trials_of(path: Path) -> list[dict]:
    from vswrist_gym.sweep.spec import load_sweep

    return load_sweep(path).trials()


def wait_for(condition, timeout: float, what: str):
    deadline = time.time() + timeout
    while time.time() < deadline:
        got = condition()
        if got:
            return got
        time.sleep(0.5)
    raise AssertionError(f"timed out waiting for {what}")


def test_two_node_sweep_equals_serial_train_and_evaluate(cluster, tmp_path):
    """2 tasks x 2 seeds (+ the analytic baseline): every trial's per-episode metrics equal, to the last bit,
    those of `vswrist train` and `vswrist evaluate` run one after another with the same seeds and budget."""
    c, _ = cluster(2, 2)
    path = write_sweep(tmp_path, tasks=["LoadHold", "Polish"])
    text = finish(start_sweep(path, c.address, log=tmp_path / "sweep.log"), tmp_path / "sweep.log")
    assert "2 node(s)" in text and "6/6 trials done" in text
    trials = trials_of(path)
    nodes = {json.loads((Path(t["trial_dir"]) / "result.json").read_text())["node"] for t in trials}
    assert len(nodes) == 2, "the trials ran on both nodes"
    serial = tmp_path / "serial"
    config = tmp_path / "runs" / "configs" / "ppo.yaml"  # the sweep's entries (its overrides merged in)
    for t in trials:
        ev = serial / t["name"] / "eval"
        if t["kind"] == "learned":
            run = serial / t["name"] / "run"
            cli("train", "--task", t["task"], "--algo", "ppo", "--seed", t["seed"], "--timesteps", 1024,
                "--config", config, "--out", run, "--no-progress", cwd=tmp_path)
            agent = run
        else:
            agent = f"analytic:{t['stiffness']}"
        cli("evaluate", "--task", t["task"], "--agent", agent, "--episodes", 2, "--seeds", *t["eval_seeds"],
            "--out", ev, cwd=tmp_path)
        assert episodes(Path(t["trial_dir"]) / "metrics.json") == episodes(ev / "metrics.json"), t["name"]
    for task in ("LoadHold", "Polish"):  # the grid's tables, as vswrist compare writes them
        summary = json.loads((tmp_path / "out" / task / "summary.json").read_text())
        assert set(summary["rows"]) == {"PPO", "analytic:+0.00"}
        assert (tmp_path / "out" / task / "learning_curves.png").is_file()


def test_worker_node_killed_mid_trial_resumes_from_its_checkpoint(cluster, tmp_path):
    """The only node with CPUs dies while the trial trains; a new node joins: the trial is retried there, resumes
    from its last checkpoint, and finishes once, with its budget and its evaluation episodes once each."""
    c, worker = cluster(0, 2)
    budget = 6144
    path = write_sweep(tmp_path, seeds=[0], stiffness=[], timesteps={"ppo": budget},
                       overrides={"ppo": {"eval_freq": 2048, "checkpoint_freq": 1024, "n_eval_episodes": 1}})
    (trial,) = trials_of(path)
    run_dir = Path(trial["run_dir"])
    log = tmp_path / "sweep.log"
    proc = start_sweep(path, c.address, log=log)
    wait_for(lambda: (run_dir / "checkpoints" / "latest.json").is_file(), 600, "a first checkpoint")
    c.add_node(num_cpus=2, node_ip_address="127.0.0.1")
    c.remove_node(worker, allow_graceful=False)
    text = finish(proc, log)
    assert "retried from its last checkpoint" in text and "1/1 trials done" in text
    history = json.loads((run_dir / "run.json").read_text())["history"]
    statuses = [h["status"] for h in history]
    assert statuses.count("finished") == 1 and statuses[-1] == "finished", statuses
    assert "killed" in statuses, statuses  # the cut-off attempt was seen and recorded
    resumed_from = [h for h in history if h["status"] == "killed"][0]["checkpoint_step"]
    assert 0 < resumed_from < budget
    assert json.loads((run_dir / "run.json").read_text())["num_timesteps"] == budget  # no step counted twice
    eps = episodes(Path(trial["trial_dir"]) / "metrics.json")
    assert [(e["seed"], e["episode"]) for e in eps] == [(0, 0), (0, 1)]
    out = episodes(tmp_path / "out" / "LoadHold" / "eval" / "ppo" / "metrics.json")
    assert [(e["seed"], e["episode"]) for e in out] == [(0, 0), (0, 1)]


def test_driver_killed_mid_sweep_resume_skips_finished_trials(cluster, tmp_path):
    c, _ = cluster(2, 2)
    path = write_sweep(tmp_path, seeds=[0, 1, 2], episodes=1, stiffness=[0.0, 0.5], timesteps={"ppo": 2048})
    trials = trials_of(path)
    learned = [t for t in trials if t["kind"] == "learned"]
    log = tmp_path / "sweep.log"
    proc = start_sweep(path, c.address, log=log)

    def some_learned_done():
        done = [t for t in learned if (Path(t["trial_dir"]) / "result.json").is_file()]
        return done if done and len(done) < len(learned) else None

    wait_for(some_learned_done, 600, "a finished learned trial")
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    before = {t["name"]: (Path(t["trial_dir"]) / "result.json").read_bytes() for t in trials
              if (Path(t["trial_dir"]) / "result.json").is_file()}
    assert 0 < len(before) < len(trials)
    text = finish(start_sweep(path, c.address, "--resume", log=tmp_path / "resume.log"), tmp_path / "resume.log")
    assert f"{len(before)} of {len(trials)} trials already have a record: not rerun" in text
    for t in trials:
        record = (Path(t["trial_dir"]) / "result.json").read_bytes()
        if t["name"] in before:
            assert record == before[t["name"]], f"{t['name']} was rerun"
        if t["kind"] == "learned":
            history = json.loads((Path(t["run_dir"]) / "run.json").read_text())["history"]
            assert [h["status"] for h in history].count("finished") == 1, t["name"]
    out = episodes(tmp_path / "out" / "LoadHold" / "eval" / "ppo" / "metrics.json")
    assert sorted((e["seed"], e["episode"]) for e in out) == [(0, 0), (1, 0), (2, 0)]


def test_search_writes_a_best_entry_that_train_reads_without_touching_evaluation_seeds(tmp_path):
    """A tiny Optuna search (Ray embedded, no address): the best sample's learning rate, inside its range, lands
    in a hyperparameter file that `hparams.load_config` (what `vswrist train --config` uses) reads; no protocol
    evaluation (metrics.json) is run anywhere."""
    from vswrist_gym.agents import hparams

    best = tmp_path / "best_ppo.yaml"
    doc = {"mode": "search", "tasks": ["LoadHold"], "algos": ["ppo"], "seeds": [100], "stiffness": [],
           "timesteps": {"ppo": 2048},
           "overrides": {"ppo": {"eval_freq": 512, "checkpoint_freq": 1024, "n_eval_episodes": 1}},
           "runs_dir": str(tmp_path / "runs"),
           "search": {"samples": 3, "grace_steps": 1024, "seed": 1, "best_out": str(best),
                      "space": {"ppo": {"learning_rate": {"loguniform": [1.0e-4, 1.0e-3]},
                                        "gae_lambda": {"uniform": [0.9, 0.99]}}}}}
    path = tmp_path / "search.yaml"
    path.write_text(yaml.safe_dump(doc))
    log = tmp_path / "search.log"
    text = finish(subprocess.Popen([sys.executable, "-m", "vswrist_gym.cli", "sweep", str(path)],
                                   stdout=open(log, "w"), stderr=subprocess.STDOUT, env=ENV, cwd=tmp_path), log)
    assert "best eval_return" in text
    cfg = hparams.load_config("ppo", "VSWrist/LoadHold-v1", best)
    lr = cfg.algo_kwargs["learning_rate"]
    assert 1.0e-4 <= lr <= 1.0e-3 and 0.9 <= cfg.algo_kwargs["gae_lambda"] <= 0.99
    assert cfg.n_timesteps == 2048
    marker = json.loads((tmp_path / "runs" / "LoadHold" / "search_LoadHold_ppo.done.json").read_text())
    assert marker["config"]["learning_rate"] == lr
    assert not list((tmp_path / "runs").rglob("metrics.json"))


def test_search_driver_killed_resume_reruns_no_finished_sample_and_writes_the_best_once(cluster, tmp_path):
    """A search (4 samples, 2 at a time) whose driver is killed once a sample has finished: `--resume` restores
    the Tune experiment, the search ends with 4 samples (the Optuna sampler's state restored, none drawn twice),
    no finished training runs again (its run directory untouched, one 'finished' in every run's history), and the
    best entry, written once, is the sample with the highest final periodic evaluation over all 4 samples,
    those finished before the kill included (read back from the samples' own evaluation files)."""
    import numpy as np

    from vswrist_gym.agents import hparams

    c, _ = cluster(2, 2)
    samples, budget, best = 4, 2048, tmp_path / "best_ppo.yaml"
    doc = {"mode": "search", "tasks": ["LoadHold"], "algos": ["ppo"], "seeds": [100], "stiffness": [],
           "timesteps": {"ppo": budget}, "n_envs": {"ppo": 1},
           "overrides": {"ppo": {"eval_freq": 512, "checkpoint_freq": 512, "n_eval_episodes": 1}},
           "runs_dir": str(tmp_path / "runs"),
           "search": {"samples": samples, "grace_steps": budget, "seed": 3, "best_out": str(best),
                      "space": {"ppo": {"learning_rate": {"loguniform": [1.0e-4, 1.0e-3]}}}}}
    path = tmp_path / "search.yaml"
    path.write_text(yaml.safe_dump(doc))
    root = tmp_path / "runs" / "LoadHold" / "search" / "ppo"

    def finished_runs():
        out = []
        for run_json in root.glob("*/seed100/run.json"):
            try:
                if json.loads(run_json.read_text()).get("status") == "finished":
                    out.append(run_json.parent)
            except ValueError:  # being replaced
                pass
        return out

    log = tmp_path / "search.log"
    proc = start_sweep(path, c.address, "--max-concurrent", "2", log=log)
    done = wait_for(lambda: finished_runs() if 0 < len(finished_runs()) < samples else None, 600,
                    "a finished sample")
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert not best.exists(), "the kill came before the search ended"
    untouched = {run: {p: p.stat().st_mtime_ns for p in run.rglob("*") if p.is_file()} for run in done}
    text = finish(start_sweep(path, c.address, "--max-concurrent", "2", "--resume", log=tmp_path / "resume.log"),
                  tmp_path / "resume.log")
    assert "resuming the search" in text
    marker = json.loads((tmp_path / "runs" / "LoadHold" / "search_LoadHold_ppo.done.json").read_text())
    assert marker["samples"] == samples and len(marker["trials"]) == samples, marker
    sample_dirs = [root / trial_id for trial_id in marker["trials"]]
    assert {run.parent for run in untouched} <= set(sample_dirs), "a sample finished before the kill was dropped"
    for run, files in untouched.items():
        assert {p: p.stat().st_mtime_ns for p in run.rglob("*") if p.is_file()} == files, f"{run} was rerun"
    final = {}
    for d in sample_dirs:
        history = json.loads((d / "seed100" / "run.json").read_text())["history"]
        assert [h["status"] for h in history].count("finished") == 1, d.name
        with np.load(d / "seed100" / "eval" / "evaluations.npz") as ev:
            assert int(ev["timesteps"][-1]) == budget
            final[d.name] = float(ev["results"][-1].mean())
    top = max(final, key=final.get)
    lr_top = yaml.safe_load((root / top / "hparams.yaml").read_text())["VSWrist/LoadHold-v1"]["learning_rate"]
    assert hparams.load_config("ppo", "VSWrist/LoadHold-v1", best).algo_kwargs["learning_rate"] == lr_top
    written = best.read_text()
    top_level = [line for line in written.splitlines() if line.startswith("VSWrist/")]
    assert top_level == ["VSWrist/LoadHold-v1:"] and written.count("(mode: search)") == 1, written


# ------------------------------------------------------------------------------------ a cluster of `ray start`


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def ray_start_cluster(tmp_path):
    """A head and a worker node started with `ray start` as docs/training.md shows (token authentication, the
    token in ~/.ray/auth_token), in a home of the test's own. `--block` keeps each node's processes under one
    process group of ours, which the teardown ends (never `ray stop`: it stops every Ray on the machine)."""
    ray_cli = str(Path(sys.executable).parent / "ray")
    home = tmp_path / "home"
    home.mkdir()
    env = {**ENV, "HOME": str(home)}
    env.pop("RAY_AUTH_MODE", None)
    subprocess.run([ray_cli, "get-auth-token", "--generate"], env=env, check=True, capture_output=True, timeout=120)
    assert (home / ".ray" / "auth_token").is_file()
    port = _free_port()
    node_env = {**env, "RAY_AUTH_MODE": "token"}
    procs = []

    def start(*args, log: Path) -> None:
        fh = open(log, "w")
        procs.append(subprocess.Popen([ray_cli, "start", "--block", "--num-cpus", "2", "--node-ip-address",
                                       "127.0.0.1", *args], stdout=fh, stderr=subprocess.STDOUT, env=node_env,
                                      start_new_session=True))
        wait_for(lambda: "Ray runtime started" in log.read_text() or procs[-1].poll() is not None, 180,
                 f"ray start {' '.join(args)}")
        assert procs[-1].poll() is None, log.read_text()[-2000:]

    try:
        start("--head", "--port", str(port), "--include-dashboard", "false", log=tmp_path / "head.log")
        start("--address", f"127.0.0.1:{port}", log=tmp_path / "worker.log")
        yield f"127.0.0.1:{port}", env
    finally:
        for proc in reversed(procs):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


def test_sweep_joins_a_ray_start_cluster_with_token_authentication(ray_start_cluster, tmp_path):
    """Ray (2.52 on) turns token authentication on in `ray start` when a token exists; a driver given an explicit
    address does not. `vswrist sweep --address` uses the token it finds and runs on both nodes; a driver without
    a token fails with one line and leaves no sweep folder behind (the rerun needs no --resume)."""
    address, env = ray_start_cluster
    path = write_sweep(tmp_path, seeds=[0, 1])
    no_token = {**env, "HOME": str(tmp_path / "elsewhere")}
    (tmp_path / "elsewhere").mkdir()
    res = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", "sweep", str(path), "--address", address],
                         capture_output=True, text=True, env=no_token, cwd=tmp_path, timeout=600)
    assert res.returncode == 2, res.stdout + res.stderr
    lines = [x for x in res.stderr.strip().splitlines() if x.startswith("vswrist sweep")]
    assert len(lines) == 1 and "cannot join the Ray cluster" in lines[0] and "token" in lines[0], res.stderr[-2000:]
    assert not (tmp_path / "runs").exists() and not (tmp_path / "out").exists()
    log = tmp_path / "sweep.log"
    fh = open(log, "w")
    proc = subprocess.Popen([sys.executable, "-m", "vswrist_gym.cli", "sweep", str(path), "--address", address],
                            stdout=fh, stderr=subprocess.STDOUT, env=env, cwd=tmp_path)
    text = finish(proc, log)
    assert "2 node(s)" in text and "3/3 trials done" in text
    nodes = {json.loads((Path(t["trial_dir"]) / "result.json").read_text())["node"] for t in trials_of(path)}
    assert len(nodes) == 2, "the trials ran on both nodes"
