"""`vswrist sweep` without Ray: sweep files are checked before Ray starts (one-line errors naming the key), the
committed sweep files describe the grids the old bash scripts ran, a trial is idempotent, and a searched entry
goes into a hyperparameter file that `vswrist train` reads. The Ray tests are in test_sweep_ray.py (`-m ray`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from vswrist_gym.agents import hparams
from vswrist_gym.sweep.spec import SweepError, load_sweep

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENTS = ROOT / "experiments"  # a study's sweep files are in experiments/<study>/


def sweep_file(name: str) -> Path:
    """The committed sweep file `name`.yaml, in whichever study's folder holds it."""
    (found,) = EXPERIMENTS.glob(f"*/{name}.yaml")
    return found

# the CLI in a fresh interpreter in which `import ray` and `import optuna` fail, as on an installation without
# the [sweep] extra
NO_RAY = ("import sys; sys.modules['ray'] = None; sys.modules['optuna'] = None; "
          "from vswrist_gym.cli import main; sys.exit(main(sys.argv[1:]))")

GOOD = {"mode": "grid", "tasks": ["LoadHold"], "algos": ["ppo"], "seeds": [0, 1], "episodes": 1,
        "stiffness": [0.0], "timesteps": {"ppo": 1024}}


def sweep_cli(*args, cwd) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    return subprocess.run([sys.executable, "-c", NO_RAY, "sweep", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, env=env, timeout=120)


@pytest.mark.parametrize("change,key", [
    ({"budget": 5}, "budget"),                                   # unknown key
    ({"tasks": ["LoadHold", "Juggle"]}, "tasks"),                # unknown task
    ({"timesteps": {"ppo": -5}}, "timesteps.ppo"),               # negative budget
    ({"overrides": {"ppo": {"n_stepz": 4}}}, "n_stepz"),         # unknown hyperparameter in an override
    ({"search": {"samples": 2}}, "search"),                      # search settings in a grid
    ({"mode": "search", "stiffness": [], "search": {"samples": 2, "space": {"ppo": {"gamma": {"uniform": [0.9]}}}}},
     "search.space.ppo.gamma.uniform"),
])
def test_bad_sweep_file_is_one_line_naming_the_key_without_ray(tmp_path, change, key):
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump({**GOOD, **change}))
    res = sweep_cli("bad.yaml", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert key in lines[0] and "bad.yaml" in lines[0], lines[0]
    assert not list(tmp_path.glob("runs")), "nothing is written for a bad sweep file"


def test_without_ray_a_good_sweep_says_what_to_install(tmp_path):
    (tmp_path / "good.yaml").write_text(yaml.safe_dump(GOOD))
    res = sweep_cli("good.yaml", cwd=tmp_path)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert 'pip install -e ".[sweep]"' in lines[0]
    assert not (tmp_path / "runs").exists()


def _recorded(summary: dict) -> dict:
    return {"task": summary["task"], "seeds": summary["seeds"], "episodes": summary["episodes_per_seed"],
            "stiffness": summary["stiffness_levels"], "timesteps": summary["timesteps"]}


def _recorded_summary(sw, env_id: str) -> dict:
    """What the committed OUT/<Task>/summary.json of a sweep's task records about the grid that made it."""
    return _recorded(json.loads((ROOT / sw.out / env_id.split("/")[1].rsplit("-v", 1)[0] / "summary.json").read_text()))


def _as_swept(sw, env_id: str) -> dict:
    """The same quantities as the sweep file's trials for that task give them."""
    trials = [t for t in sw.trials() if t["env_id"] == env_id]
    learned = [t for t in trials if t["kind"] == "learned"]
    return {"task": env_id, "seeds": sorted({t["seed"] for t in learned}), "episodes": sw.episodes,
            "stiffness": [t["stiffness"] for t in trials if t["kind"] == "analytic"],
            "timesteps": {t["algo"]: t["timesteps"] for t in learned}}


@pytest.mark.parametrize("name,channel", [
    ("every_task", None), ("long", None), ("long200", None), ("sac_drill", None), ("sac_long", None),
    ("sac_insertion", None), ("sac_tuned", None),
    ("ablation_posture_only", "stiffness_scale"), ("ablation_stiffness_only", "posture_scale"),
    ("long_stiffness", "posture_scale"), ("hammer_stiffness", "posture_scale"),
    ("tuned_stiffness", "posture_scale"), ("tuned_stiffness_fs1", "posture_scale"),
    ("tuned_stiffness_fs4", "posture_scale"), ("tuned_stiffness_fs4_drill", "posture_scale"),
    ("sac_hammer", None), ("sac_hammer_posture_only", "stiffness_scale"),
    ("sac_insertion_posture_only", "stiffness_scale"),
    ("sac_stiffness", "posture_scale"), ("impact_stiffness_symmetric", "posture_scale"),
    ("lstm_stiffness", "posture_scale"),
])
def test_committed_sweeps_describe_the_committed_tables(name, channel):
    """Each sweep file reruns the grid its committed tables came from: the tasks, seeds, episodes, stiffness
    levels and budgets recorded in OUT/<Task>/summary.json, and an ablation switches off exactly one channel."""
    sw = load_sweep(sweep_file(name))
    algo = sw.algos[0]
    # the channels are checked against the hyperparameter file the sweep trains from (a tuned file sets its own)
    base = hparams.load_file(ROOT / sw.configs[algo] if algo in sw.configs else hparams.default_config_path(algo))
    for env_id in sw.env_ids:
        assert _as_swept(sw, env_id) == _recorded_summary(sw, env_id)
        residual = sw.entries[(sw.algos[0], env_id)]["env_kwargs"]["residual"]
        for ch in ("stiffness_scale", "posture_scale"):
            assert residual[ch] == (0.0 if ch == channel else base[env_id]["env_kwargs"]["residual"][ch])


def test_every_committed_sweep_file_loads():
    files = sorted(f for f in EXPERIMENTS.glob("*/*.yaml") if "mode" in yaml.safe_load(f.read_text()))
    assert len(files) >= 37  # the 37 sweep records the studies were run from
    for f in files:
        sw = load_sweep(f)
        assert sw.trials() or sw.mode == "search"
        study = f.parent.relative_to(ROOT)
        if sw.mode == "grid":  # a study's outputs are written into its own folder
            assert sw.out == study or study in sw.out.parents, f"{f}: out {sw.out} is outside {study}"
        for algo, path in sw.configs.items():  # tuned entries: a study's own <algo>.yaml, never package data
            assert (ROOT / path).is_file() and Path(path).name == f"{algo}.yaml", f"{f}: configs.{algo} {path}"
            assert Path(path).parts[0] == "experiments", f"{f}: configs.{algo} {path}"
        best = sw.search.get("best_out")
        if best is not None:
            assert Path(best).parts[0] != "vswrist_gym", f"{f}: a search writes into the package: {best}"


def test_a_recorded_trial_is_not_rerun(tmp_path):
    """run_trial twice: the second call returns the first call's record and rewrites nothing."""
    from vswrist_gym.sweep.trial import run_trial

    (tmp_path / "s.yaml").write_text(yaml.safe_dump({**GOOD, "algos": [], "timesteps": {}, "seeds": [3], "runs_dir": str(tmp_path / "r"),
                                                     "out": str(tmp_path / "o")}))
    (trial,) = load_sweep(tmp_path / "s.yaml").trials()
    first = run_trial(trial, log=lambda m: None)
    files = {p: p.stat().st_mtime_ns for p in Path(trial["trial_dir"]).iterdir()}
    again = run_trial(trial, log=lambda m: None)
    assert again.pop("skipped") is True and again == json.loads(json.dumps(first))
    assert {p: p.stat().st_mtime_ns for p in Path(trial["trial_dir"]).iterdir()} == files
    metrics = json.loads((Path(trial["trial_dir"]) / "metrics.json").read_text())
    assert [(e["seed"], e["episode"]) for e in metrics["episodes"]] == [(3, 0)]


def test_best_entry_is_written_where_vswrist_train_reads_it(tmp_path):
    from vswrist_gym.sweep.best import write_best_entry

    target = tmp_path / "tuned_sac.yaml"
    pendulum = hparams.load_file(hparams.default_config_path("sac"))["Pendulum-v1"]
    write_best_entry(target, "sac", "Pendulum-v1", {**pendulum, "learning_rate": 7.5e-4}, comment="test")
    polish = hparams.load_file(hparams.default_config_path("sac"))["VSWrist/Polish-v1"]
    write_best_entry(target, "sac", "VSWrist/Polish-v1", {**polish, "gamma": 0.97})
    assert hparams.load_config("sac", "Pendulum-v1", target).algo_kwargs["learning_rate"] == 7.5e-4  # kept
    assert hparams.load_config("sac", "VSWrist/Polish-v1", target).algo_kwargs["gamma"] == 0.97
    with pytest.raises(hparams.ConfigError, match="gama"):
        write_best_entry(target, "sac", "Pendulum-v1", {**pendulum, "gama": 0.9})
    assert hparams.load_config("sac", "Pendulum-v1", target).algo_kwargs["learning_rate"] == 7.5e-4


def test_a_second_sweep_in_the_same_runs_dir_is_refused(tmp_path):
    from vswrist_gym.sweep.cli import RECORD_FILE, check_state

    (tmp_path / "s.yaml").write_text(yaml.safe_dump({**GOOD, "runs_dir": str(tmp_path / "r")}))
    sw = load_sweep(tmp_path / "s.yaml")
    with pytest.raises(SweepError, match="nothing to resume"):
        check_state(sw, resume=True)
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / RECORD_FILE).write_text(json.dumps({"sweep": {**GOOD, "seeds": [0]}}))
    with pytest.raises(SweepError, match="--resume"):
        check_state(sw, resume=False)
    with pytest.raises(SweepError, match="changed"):
        check_state(sw, resume=True)


def test_an_override_never_replaces_a_whole_value_by_some_of_its_fields():
    from vswrist_gym.sweep.spec import deep_merge

    base = {"policy_kwargs": "dict(net_arch=[64, 64], log_std_init=-1.5)", "env_kwargs": {"a": 1, "b": {"c": 2}}}
    assert deep_merge(base, {"env_kwargs": {"b": {"c": 3}}})["env_kwargs"] == {"a": 1, "b": {"c": 3}}
    with pytest.raises(SweepError, match="policy_kwargs"):
        deep_merge(base, {"policy_kwargs": {"log_std_init": -1.0}})


def test_trial_cpus_follow_the_vec_env(tmp_path):
    """A batched run steps its worlds on one thread and asks Ray for one CPU, whatever its n_envs; a run with a
    process per env asks for n_envs."""
    doc = dict(GOOD, stiffness=[], n_envs={"ppo": 8})
    (tmp_path / "batch.yaml").write_text(yaml.safe_dump(doc))
    (tmp_path / "sub.yaml").write_text(yaml.safe_dump(dict(doc, overrides={"ppo": {"vec_env": "subproc"}})))
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        batch, sub = (load_sweep(tmp_path / f).trials() for f in ("batch.yaml", "sub.yaml"))
    finally:
        os.chdir(cwd)
    assert [t["cpus"] for t in batch] == [1, 1] and [t["n_envs"] for t in batch] == [8, 8]
    assert [t["cpus"] for t in sub] == [8, 8]


def _episode_keys(out: Path, env_id: str, agent: str = "ppo") -> set:
    doc = json.loads((ROOT / out / env_id.split("/")[1].rsplit("-v", 1)[0] / "eval" / agent / "metrics.json").read_text())
    return {(e["seed"], e["reset_seed"]) for e in doc["episodes"]}


@pytest.mark.parametrize("full,ablation,held", [
    ("contribution_polish_full", "contribution_polish_posture_only", {}),
    ("contribution_polish_full", "contribution_polish_posture_only_s05", {"stiffness_nominal": 0.5}),
])
def test_contribution_pairs_differ_only_in_the_stiffness_channel(full, ablation, held):
    """A stiffness-contribution pair (experiments/contribution_polish/NOTES.md) trains the same entry on the same
    seeds and evaluates it on the same episodes; the ablation closes the stiffness channel (and may hold another
    constant), the posture channel is open in both. Each file's committed summary records what the file runs."""
    sws = [load_sweep(sweep_file(name)) for name in (full, ablation)]
    assert sws[0].env_ids == sws[1].env_ids and sws[0].seeds == sws[1].seeds
    assert sws[0].episodes == sws[1].episodes and sws[0].timesteps == sws[1].timesteps
    for sw in sws:
        for env_id in sw.env_ids:
            assert _as_swept(sw, env_id) == _recorded_summary(sw, env_id)
    for env_id in sws[0].env_ids:
        a, b = (sw.entries[("ppo", env_id)] for sw in sws)
        ra, rb = a["env_kwargs"]["residual"], b["env_kwargs"]["residual"]
        assert ra["stiffness_scale"] > 0 and rb["stiffness_scale"] == 0.0
        assert ra["posture_scale"] == rb["posture_scale"] > 0
        assert {k: rb[k] for k in held} == held
        strip = lambda e: {**e, "env_kwargs": {**e["env_kwargs"], "residual": {  # noqa: E731
            k: v for k, v in e["env_kwargs"]["residual"].items() if k != "stiffness_scale" and k not in held}}}
        assert strip(a) == strip(b)
        assert _episode_keys(sws[0].out, env_id) == _episode_keys(sws[1].out, env_id)
