"""Cross-task aggregation (rliable): normalisation against known anchors and the statistics' defining cases."""

import json

import numpy as np
import pytest

from vswrist_gym.agents import aggregate as agg

pytest.importorskip("rliable")


def _summary(task, base, agent_returns, seeds=None):
    seeds = seeds or list(range(len(base)))
    row = lambda v: {"return": {"mean": float(np.mean(v)), "per_seed": list(v), "seeds": seeds}}  # noqa: E731
    return {"task": f"VSWrist/{task}-v0",
            "rows": {"analytic:+0.00": row(base), "analytic:+1.00": row([b - 50 for b in base]),
                     "PPO": row(agent_returns)}}


def test_normalised_anchors():
    """The best constant scores 0 and an agent that gains exactly the headroom scores 1, seed by seed."""
    base = [-100.0, -120.0, -90.0]
    s = _summary("Polish", base, [b + 20.0 for b in base])
    assert agg.normalised(s, "PPO", 20.0) == pytest.approx({0: 1.0, 1: 1.0, 2: 1.0})
    s = _summary("Polish", base, base)
    assert agg.normalised(s, "PPO", 20.0) == pytest.approx({0: 0.0, 1: 0.0, 2: 0.0})
    # The better of the two constants is the anchor, not the first listed.
    s["rows"]["analytic:+0.00"], s["rows"]["analytic:+1.00"] = s["rows"]["analytic:+1.00"], s["rows"]["analytic:+0.00"]
    assert agg.normalised(s, "PPO", 20.0) == pytest.approx({0: 0.0, 1: 0.0, 2: 0.0})


def test_constant_scores_and_dominance():
    """IQM of a constant score is that score with a zero-width interval; an agent better on every run and task
    improves on the other with probability 1 (Mann-Whitney's U statistic at its maximum)."""
    a = np.full((5, 3), 0.4)
    b = np.full((5, 3), -0.2) + np.linspace(0, 0.1, 15).reshape(5, 3)
    r = agg.aggregate({"a": a, "b": b}, reps=200)
    iqm = r["metrics"]["a"]["iqm"]
    assert iqm["estimate"] == pytest.approx(0.4) and iqm["low"] == pytest.approx(0.4)
    assert iqm["high"] == pytest.approx(0.4)
    assert r["metrics"]["a"]["optimality_gap"]["estimate"] == pytest.approx(0.6)
    assert r["probability_of_improvement"]["a > b"]["estimate"] == pytest.approx(1.0)
    assert r["probability_of_improvement"]["b > a"]["estimate"] == pytest.approx(0.0)


def test_iqm_is_the_middle_half():
    """IQM of 8 runs on one task is the mean of the 3rd to 6th order statistics."""
    x = np.array([[9.0], [1.0], [7.0], [3.0], [5.0], [2.0], [8.0], [4.0]])
    r = agg.aggregate({"x": x}, reps=100)
    assert r["metrics"]["x"]["iqm"]["estimate"] == pytest.approx((3 + 4 + 5 + 7) / 4)
    lo, hi = r["metrics"]["x"]["iqm"]["low"], r["metrics"]["x"]["iqm"]["high"]
    assert 1.0 <= lo <= 4.75 <= hi <= 9.0


def test_cli_end_to_end(tmp_path):
    for task, gain in (("Polish", 10.0), ("Impact", 30.0)):
        d = tmp_path / "res" / task
        d.mkdir(parents=True)
        base = [-100.0, -110.0, -95.0]
        (d / "summary.json").write_text(json.dumps(_summary(task, base, [b + gain for b in base])))
    hr = tmp_path / "headroom.json"
    hr.write_text(json.dumps({"tasks": {"Polish": {"headroom": 20.0}, "Impact": {"headroom": 30.0}}}))
    assert agg.main(["--run", f"PPO={tmp_path / 'res'}:PPO", "--headroom", str(hr),
                     "--out", str(tmp_path / "out"), "--reps", "200"]) == 0
    result = json.loads((tmp_path / "out" / "aggregate.json").read_text())
    assert result["tasks"] == ["Impact", "Polish"]
    # Scores are 0.5 on Polish and 1.0 on Impact: the mean over tasks is 0.75.
    assert result["metrics"]["PPO"]["mean"]["estimate"] == pytest.approx(0.75)
    assert (tmp_path / "out" / "profiles.png").stat().st_size > 1000


@pytest.mark.parametrize("headroom, field", [({"tasks": {"Polish": {"headroom": -1}}}, "tasks.Polish.headroom"),
                                             ({"tasks": {"Polish": {"headroom": "x"}}}, "tasks.Polish.headroom")])
def test_bad_headroom_names_the_field(tmp_path, headroom, field):
    f = tmp_path / "h.json"
    f.write_text(json.dumps(headroom))
    with pytest.raises(agg.AggregateError, match=field.replace(".", r"\.")):
        agg.load_headroom(f)


def test_bad_inputs_are_one_line_errors(tmp_path, capsys):
    hr = tmp_path / "h.json"
    hr.write_text("{not json")
    with pytest.raises(SystemExit) as e:
        agg.main(["--run", f"PPO={tmp_path}:PPO", "--headroom", str(hr), "--out", str(tmp_path / "o")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "cannot read the headroom file" in err
    with pytest.raises(agg.AggregateError, match="LABEL=RESULTS_DIR:AGENT"):
        agg._parse_run("nolabel")


def test_probe_headroom_json_feeds_aggregate(tmp_path, capsys):
    """The probe's --headroom-json is what `vswrist aggregate --headroom` reads: every task written has a positive
    gain, equal to the larger paired gain of the printed table."""
    from vswrist_gym.tools import probe

    out = tmp_path / "headroom.json"
    assert probe.main(["--tasks", "Impact", "--episodes", "2", "--headroom", "--headroom-json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert "Impact" in doc["tasks"]  # its rule gains about +55 on held-out episodes (docs/environments.md)
    for task, entry in doc["tasks"].items():
        assert entry["headroom"] == max(entry["rule"][0], entry["schedule"][0]) > 0
    assert agg.load_headroom(out) == {t: e["headroom"] for t, e in doc["tasks"].items()}


def test_a_task_folder_is_not_replaced_by_another_run_of_the_task(tmp_path):
    """A results folder holds <Task>/ folders and also main_job/ (another Polish run): only Polish/ counts as Polish."""
    base = [-100.0, -110.0]
    for name, gain in (("Polish", 10.0), ("main_job", 50.0)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps(_summary("Polish", base, [b + gain for b in base])))
    s = agg.load_summaries(tmp_path)
    assert agg.normalised(s["Polish"], "PPO", 10.0) == pytest.approx({0: 1.0, 1: 1.0})
    assert set(agg.load_summaries(tmp_path / "main_job")) == {"Polish"}


def test_probability_of_improvement_is_rliables_to_the_bit():
    """The pair count equals rliable's rank-based Mann-Whitney statistic exactly, ties and identical runs included,
    and so does every bootstrap interval drawn with the same seed."""
    from rliable import library, metrics

    rng = np.random.default_rng(3)
    cases = [(rng.normal(size=(10, 2)), rng.normal(size=(10, 2))),
             (np.round(rng.normal(size=(10, 3)), 1), np.round(rng.normal(size=(7, 3)), 1)),  # many ties
             (np.zeros((10, 2)), np.round(rng.normal(size=(10, 2)), 0)),  # the best constant's scores: all 0
             ]
    x = rng.normal(size=(10, 2))
    cases.append((x, x.copy()))  # identical runs: 0.5
    for a, b in cases:
        assert agg.probability_of_improvement(a, b) == metrics.probability_of_improvement(a, b)
        assert agg.probability_of_improvement(b, a) == metrics.probability_of_improvement(b, a)
    a, b = cases[1]
    np.random.seed(0)
    mine = library.get_interval_estimates({"x": (a, b)}, agg.probability_of_improvement, reps=200)
    np.random.seed(0)
    theirs = library.get_interval_estimates({"x": (a, b)}, metrics.probability_of_improvement, reps=200)
    assert np.array_equal(mine[0]["x"], theirs[0]["x"]) and np.array_equal(mine[1]["x"], theirs[1]["x"])
