"""The leaderboard (vswrist_gym/tools/benchmark.py): its tracks are what their names say, the freeze test holds
what it claims, its statistics agree with hand computations, it reads only gated tasks and held-out episodes, and
the committed table is what the command writes from the committed result files."""

from __future__ import annotations

import json
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from vswrist_gym.agents.protocol import HELDOUT_EVAL_SEEDS, TUNING_EVAL_SEEDS, reset_seed
from vswrist_gym.tools import benchmark, gate

ROOT = Path(__file__).resolve().parents[1]
GATE_DIR = ROOT / "experiments" / "gate"
OUT = ROOT / "experiments" / "leaderboard"


# ------------------------------------------------------------------------------------------------ tracks


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_tracks_are_what_their_names_say(algo):
    from vswrist_gym.agents.hparams import resolve_entry, track_of

    env_id = "VSWrist/Throw-v0"
    kw = {}
    for track in benchmark.TRACKS:
        doc = benchmark.track_entry(env_id, algo, track, best_constant=0.5)
        cfg = resolve_entry(algo, env_id, {**doc[env_id], **doc["vswrist"][env_id]})
        kw[track] = cfg.env_kwargs["residual"]
    # the hyperparameter module's own classification of each track's action space
    assert track_of({"action_mode": "residual", "residual": kw["stiffness"]}) == "stiffness"
    assert track_of({"action_mode": "residual", "residual": kw["full"]}) == "full"
    assert kw["stiffness"]["stiffness_scale"] > 0 and kw["full"]["stiffness_scale"] > 0
    assert kw["full"]["posture_scale"] == gate.POSTURE_SCALE   # Throw's entries are stiffness-only
    assert kw["posture"] == {**kw["full"], "stiffness_scale": 0.0, "stiffness_nominal": 0.5}


def test_the_posture_track_is_the_gates_posture_only_policy():
    """Two routes to one configuration: the leaderboard's posture/PPO cell trains what the gate's necessity did."""
    for env_id in ("VSWrist/Throw-v0", "VSWrist/Hammer-v0"):
        assert benchmark.track_entry(env_id, "ppo", "posture", -0.5, budget=80_000) == \
            gate.posture_only_entry(env_id, -0.5, budget=80_000)


def test_unknown_track_and_missing_entry_are_refused():
    with pytest.raises(benchmark.BenchmarkError, match="track must be one of"):
        benchmark.track_entry("VSWrist/Throw-v0", "ppo", "posture-only", 0.0)
    with pytest.raises(gate.GateError, match="no entry for"):
        benchmark.track_entry("VSWrist/Nothing-v0", "ppo", "full", 0.0)


# ------------------------------------------------------------------------------------------------ freeze test


class _Constant:
    """A residual policy with a fixed stiffness action and a posture trim that varies with the observation."""

    def __init__(self, a: float):
        self.a = a

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(obs, dtype=np.float32)
        act = np.zeros(obs.shape[:-1] + (4,), dtype=np.float32)
        act[..., 0] = np.tanh(obs[..., 0])
        act[..., 3] = self.a
        return act, None


@pytest.mark.parametrize("env_id, residual", [
    ("VSWrist/Throw-v0", {"posture_scale": 0.05, "stiffness_scale": 2.0, "stiffness_nominal": 0.0}),
    ("VSWrist/Hammer-v0", {"posture_scale": 0.05, "stiffness_scale": 1.0}),   # the task's own nominal, -0.5
])
def test_freezing_a_constant_stiffness_changes_nothing(env_id, residual):
    """The freeze test recovers the held value from the episode's own internal torque (lam -> command -> action,
    the inverse of the action's map): for a policy whose stiffness never varies it must replay the same
    episodes, so the variation of the stiffness earns exactly 0."""
    kwargs = {"action_mode": "residual", "residual": residual}
    venv = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", **kwargs)
    env = gym.make(env_id, **kwargs)
    try:
        seeds = HELDOUT_EVAL_SEEDS[:1]
        recs = benchmark._records(venv, _Constant(0.3), seeds)
        commands = [np.mean([env.unwrapped.lam_to_stiffness_command(l) for l in tr.lam]) for _, tr in recs]
        nominal = residual.get("stiffness_nominal", -0.5)
        expected = nominal + residual["stiffness_scale"] * 0.3          # s = nominal + scale a
        assert commands == pytest.approx([expected] * 2, abs=1e-7)     # a float32 action
        held = benchmark.FrozenStiffness(_Constant(-0.7), benchmark.held_actions(env, commands))
        again = benchmark._records(venv, held, seeds)
        assert [r["return"] for r, _ in again] == [r["return"] for r, _ in recs]
        other = benchmark._records(venv, _Constant(-0.7), seeds)   # without the freeze: another stiffness
        assert [r["return"] for r, _ in other] != [r["return"] for r, _ in recs]
    finally:
        venv.close()
        env.close()


def test_evaluation_reads_held_out_episodes_only(tmp_path):
    with pytest.raises(gate.GateError, match="held-out"):
        benchmark.evaluate_run(tmp_path, "VSWrist/Throw-v0", seeds=TUNING_EVAL_SEEDS[:1])


# ------------------------------------------------------------------------------------------------ statistics


def _run(returns, frozen=None, success=None):
    run = {"returns": list(returns), "success": list(success or [0.0] * len(returns))}
    if frozen is not None:
        run["frozen_returns"] = list(frozen)
    return run


def test_seed_scores_by_hand():
    s = benchmark.seed_scores(_run([3.0, 5.0], frozen=[2.0, 2.0], success=[1.0, 0.0]), [1.0, 1.0], headroom=4.0)
    assert s == {"return": 4.0, "vs_constant": 3.0, "score": 0.75, "success": 0.5, "freeze": 2.0}


def test_learned_needs_both_intervals_above_zero():
    const = [0.0] * 4
    gains = {"0": _run([1, 1.2, 0.8, 1], frozen=[0, 0.1, 0, 0]), "1": _run([1.1, 1, 0.9, 1], frozen=[0, 0, 0.1, 0]),
             "2": _run([0.9, 1, 1.1, 1], frozen=[0.1, 0, 0, 0])}
    assert benchmark.cell_summary({"runs": gains}, const, 1.0)["learned"]
    no_freeze = {k: _run(v["returns"], frozen=v["returns"]) for k, v in gains.items()}   # variation earns 0
    assert not benchmark.cell_summary({"runs": no_freeze}, const, 1.0)["learned"]
    posture = {k: _run(v["returns"]) for k, v in gains.items()}                          # no freeze test
    assert not benchmark.cell_summary({"runs": posture}, const, 1.0)["learned"]


def _doc(task, headroom, scores):
    const = [10.0, 10.0]
    runs = {str(k): _run([10.0 + s * headroom] * 2, frozen=[10.0] * 2) for k, s in enumerate(scores)}
    return {"task": task, "gate": {"constant_returns": const, "headroom": headroom, "best_constant": 0.0},
            "cells": {"stiffness/ppo": {"runs": runs}}, "commands": ["vswrist benchmark"]}


def test_aggregate_by_hand():
    """IQM = the 25 % trimmed mean of all runs x tasks; P(better than the constant) = per task the share of runs
    above 0 (a tie counts one half), averaged over tasks."""
    docs = [_doc("A", 2.0, [1.0, -1.0, 0.0, 2.0]), _doc("B", 5.0, [0.5, 0.5, 3.0, -2.0])]
    m = benchmark.score_matrices(docs)
    assert m["stiffness/ppo"].shape == (4, 2) and not m["best constant"].any()
    from vswrist_gym.agents.aggregate import aggregate

    agg = aggregate(m, reps=200)
    # sorted: -2 -1 0 .5 .5 1 2 3; drop two each side -> 0, .5, .5, 1
    assert agg["metrics"]["stiffness/ppo"]["iqm"]["estimate"] == pytest.approx(0.5)
    assert agg["probability_of_improvement"]["stiffness/ppo > best constant"]["estimate"] == \
        pytest.approx(((1 + 0 + 0.5 + 1) / 4 + (1 + 1 + 1 + 0) / 4) / 2)
    table = benchmark.leaderboard(docs, reps=200)
    assert "| stiffness/ppo | 4 x 2 | +0.50" in table


# ------------------------------------------------------------------------------------------------ gated tasks, resume


def test_headline_tasks_are_the_ids_that_pass_the_gate():
    """Recomputed from each gate file's per-episode returns, not from its stored verdict."""
    expected = []
    for path in sorted(GATE_DIR.glob("*.json")):
        doc = json.loads(path.read_text())
        if not (doc.get("headroom") and doc.get("necessity") and doc.get("feedback")):
            continue
        hr = doc["headroom"]["rule_minus_constant"]
        const = doc["headroom"]["returns"]["constant"][f"{doc['selection']['best_constant']:+.1f}"]
        fb = gate.paired(doc["feedback"]["returns"], const)
        # the feedback's share: its mean gain + 1.96 s.e., over the headroom, below 0.5
        if hr["mean"] >= gate.HEADROOM_SE * hr["se"] and gate.necessity_summary(doc)["passes"] and \
                (fb["mean"] + 1.959964 * fb["se"]) / hr["mean"] < gate.NECESSITY_SHARE:
            expected.append(doc["task"])
    assert "VSWrist/Throw-v0" in expected
    assert sorted(benchmark.headline_tasks(GATE_DIR)) == sorted(expected)
    with pytest.raises(benchmark.BenchmarkError, match="does not pass the validity gate"):
        benchmark.gate_block("VSWrist/Hammer-v0", GATE_DIR)


def test_a_result_made_with_another_budget_is_refused(tmp_path):
    env_id = "VSWrist/Throw-v0"
    doc = {"task": env_id, "cells": {}, "gate": benchmark.gate_block(env_id, GATE_DIR),
           "protocol": benchmark.protocol_block([0, 1], {"ppo": 80_000})}
    (tmp_path / "Throw-v0.json").write_text(json.dumps(doc))
    with pytest.raises(benchmark.BenchmarkError, match="budget of 80000"):
        benchmark.run_task(env_id, tmp_path, tmp_path / "runs", GATE_DIR, ["stiffness"], ["ppo"], [0, 1], budget=999)
    assert not (tmp_path / "runs").exists()


def test_runs_made_with_another_entry_are_refused(tmp_path):
    env_id = "VSWrist/Throw-v0"
    gate_ = benchmark.gate_block(env_id, GATE_DIR)
    budget = benchmark.cell_budget(env_id, "ppo", None)  # the packaged entry's: only the entry differs
    entry = benchmark.track_entry(env_id, "ppo", "stiffness", gate_["best_constant"], budget)
    entry[env_id]["learning_rate"] = 1.0   # what a changed configs/ppo.yaml would give
    doc = {"task": env_id, "gate": gate_, "protocol": benchmark.protocol_block([0, 1], {"ppo": budget}),
           "cells": {"stiffness/ppo": {"entry": entry, "runs": {"0": _run([1.0, 2.0])}}}}
    (tmp_path / "Throw-v0.json").write_text(json.dumps(doc))
    with pytest.raises(benchmark.BenchmarkError, match="another hyperparameter entry"):
        benchmark.run_task(env_id, tmp_path, tmp_path / "runs", GATE_DIR, ["stiffness"], ["ppo"], [0, 1])
    assert not (tmp_path / "runs").exists()


def test_the_committed_leaderboard_is_what_the_command_writes():
    # the headline suite's result files (an id that left the suite keeps its file, out of the table)
    headline = set(benchmark.headline_tasks(GATE_DIR))
    docs = [d for d in (json.loads(p.read_text()) for p in sorted(OUT.glob("*.json"))) if d["task"] in headline]
    if not docs:
        pytest.skip("no leaderboard results committed")
    order = {t: i for i, t in enumerate(gym.registry)}
    docs.sort(key=lambda d: order.get(d["task"], math.inf))
    text = (ROOT / "docs" / "leaderboard.md").read_text()
    assert benchmark.leaderboard(docs) in text


@pytest.mark.slow
def test_benchmark_end_to_end(tmp_path):
    """The real command on a tiny budget: trains, scores on the held-out episodes, writes the table."""
    out = tmp_path / "out"
    rc = benchmark.main(["--tasks", "VSWrist/Throw-v0", "--tracks", "stiffness", "--algos", "ppo", "--train-seeds",
                         "0", "1", "--budget", "256", "--out", str(out), "--runs-dir", str(tmp_path / "runs"),
                         "--gate-dir", str(GATE_DIR)])
    assert rc == 0
    doc = json.loads((out / "Throw-v0.json").read_text())
    run = doc["cells"]["stiffness/ppo"]["runs"]["0"]
    assert len(run["returns"]) == len(run["frozen_returns"]) == 100
    assert doc["gate"]["reset_seeds"][:2] == [reset_seed(HELDOUT_EVAL_SEEDS[0], 0), reset_seed(HELDOUT_EVAL_SEEDS[0], 1)]


@pytest.mark.slow
def test_jobs_change_nothing_but_the_wall_time(tmp_path):
    """`--jobs 2` trains the seeds in two processes at once; every run's numbers equal those of one job, and the
    runs are stored in seed order."""
    docs = {}
    for jobs in (1, 2):
        out = tmp_path / f"out{jobs}"
        rc = benchmark.main(["--tasks", "VSWrist/Hammer-v1", "--tracks", "stiffness", "--algos", "ppo",
                             "--train-seeds", "1", "0", "--budget", "256", "--out", str(out), "--runs-dir",
                             str(tmp_path / f"runs{jobs}"), "--gate-dir", str(GATE_DIR), "--jobs", str(jobs)])
        assert rc == 0
        docs[jobs] = json.loads((out / "Hammer-v1.json").read_text())["cells"]["stiffness/ppo"]["runs"]
    assert list(docs[2]) == ["0", "1"]
    for s in ("0", "1"):
        for key in ("returns", "frozen_returns", "mean_commands", "success"):
            assert docs[1][s][key] == docs[2][s][key]
