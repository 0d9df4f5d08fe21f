"""`vswrist track`: the committed track files name runs of their own track, and the tables agree with a second
computation from the per-episode evaluation files (NumPy means, SciPy's Student-t quantile)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from vswrist_gym.tools import track as T

ROOT = Path(__file__).resolve().parents[1]
TRACKS = ROOT / "vswrist_gym" / "configs" / "tracks"


@pytest.fixture(autouse=True)
def _at_root(monkeypatch):
    monkeypatch.chdir(ROOT)  # the track and sweep files name paths from the repository root


def _returns(path: Path) -> dict[int, np.ndarray]:
    doc = json.loads(path.read_text())
    by: dict[int, list] = {}
    for e in sorted(doc["episodes"], key=lambda e: (e["seed"], e["reset_seed"])):
        by.setdefault(int(e["seed"]), []).append(float(e["return"]))
    return {s: np.array(v) for s, v in by.items()}


def _interval(x: np.ndarray) -> tuple[float, float, float]:
    half = stats.t.ppf(0.975, len(x) - 1) * x.std(ddof=1) / math.sqrt(len(x))
    return x.mean(), x.mean() - half, x.mean() + half


def _seed_means(folder: Path, row: dict) -> dict[str, np.ndarray]:
    """Per agent folder name, the per-seed mean returns: from the episode files, or where a folder keeps only its
    summary (experiments/polish_compare), from the summary's per-seed means."""
    if (folder / "eval").is_dir():
        names = [n.lower().replace("analytic:", "analytic_") for n in
                 json.loads((folder / "summary.json").read_text())["rows"]]  # the agents the table compares
        evals = {n: _returns(folder / "eval" / n / "metrics.json") for n in names}
        for r in evals.values():  # paired: every agent on the same episodes
            assert [len(v) for v in r.values()] == [row["episodes"]] * row["seeds"]
        return {name: np.array([r[s].mean() for s in sorted(r)]) for name, r in evals.items()}
    rows = json.loads((folder / "summary.json").read_text())["rows"]
    return {name.lower().replace("analytic:", "analytic_"): np.array(r["return"]["per_seed"]) for name, r in rows.items()}


def _check_row(row: dict, folder: Path) -> None:
    means = _seed_means(folder, row)
    constants = [n for n in means if n.startswith("analytic_")]
    best = max(constants, key=lambda n: means[n].mean())
    assert row["best"] == best.replace("analytic_", "analytic:")
    m, lo, hi = _interval(means[row["agent"].lower()])
    assert (row["return"]["mean"], row["return"]["low"], row["return"]["high"]) == pytest.approx((m, lo, hi), abs=1e-9)
    bm, blo, bhi = _interval(means[best])
    d = _interval(means[row["agent"].lower()] - means[best])
    assert (row["paired"]["mean"], row["paired"]["low"], row["paired"]["high"]) == pytest.approx(d, abs=1e-9)
    expected = "beats" if lo > bhi else "worse" if hi < blo else "overlap"
    assert row["verdict"] == expected


@pytest.mark.parametrize("name", ["stiffness", "full"])
def test_committed_track_tables_agree_with_the_episode_files(name):
    doc, rows, text = T.build(TRACKS / f"{name}.yaml")
    _, runs = T.load_track(TRACKS / f"{name}.yaml")
    assert len(rows) == len(runs) and doc["track"] == name
    for run, row in zip(runs, rows):
        _check_row(row, run.folder)
        if run.ablation is not None:  # full - posture-only, per seed on the same episodes
            full = _returns(run.folder / "eval" / run.agent / "metrics.json")
            abl = _returns(run.ablation.out / run.task / "eval" / run.agent / "metrics.json")
            d = np.array([full[s].mean() - abl[s].mean() for s in sorted(full)])
            c = row["contribution"]
            assert (c["mean"], c["low"], c["high"]) == pytest.approx(_interval(d), abs=1e-9)
    # the committed tables are what the command writes from the committed results
    committed = (ROOT / doc["out"]).read_text()
    assert text in committed


def test_every_run_is_on_its_track():
    for name in ("stiffness", "full"):
        _, runs = T.load_track(TRACKS / f"{name}.yaml")
        for run in runs:
            if run.sweep is not None:
                residual = run.sweep.entries[(run.agent, run.env_id)]["env_kwargs"]["residual"]
                assert (float(residual["posture_scale"]) == 0.0) == (name == "stiffness"), run.source


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "t.yaml"
    p.write_text(text)
    return p


def _sw(name: str) -> str:
    """The committed sweep file `name`.yaml, as a path from the repository root (studies keep theirs in
    experiments/<study>/)."""
    (found,) = ROOT.glob(f"experiments/*/{name}.yaml")
    return str(found.relative_to(ROOT))


@pytest.mark.parametrize("text, message", [
    ("track: stiffness\nheadroom: h\nout: o\nruns: []\nextra: 1\n", "unknown key 'extra'"),
    ("track: both\nheadroom: h\nout: o\nruns: [{task: Drill}]\n", "'track' must be one of"),
    ("track: stiffness\nheadroom: h\nout: o\nruns: [{task: Drill, agent: ppo}]\n", "exactly one of 'sweep'"),
    (f"track: stiffness\nheadroom: h\nout: o\nruns: [{{task: Hammer, agent: ppo, sweep: {_sw('long')}}}]\n",
     "does not run Hammer"),
    (f"track: stiffness\nheadroom: h\nout: o\nruns: [{{task: Drill, agent: sac, sweep: {_sw('long')}}}]\n",
     "trains ppo, not sac"),
    (f"track: full\nheadroom: h\nout: o\nruns: [{{task: Drill, agent: ppo, "
     f"sweep: {_sw('tuned_stiffness')}}}]\n", "on the stiffness track, not the full track"),
    (f"track: full\nheadroom: h\nout: o\nruns: [{{task: Drill, agent: ppo, sweep: {_sw('every_task')}, "
     f"ablation: {_sw('long')}}}]\n", "residual.stiffness_scale 0"),
    (f"track: full\nheadroom: h\nout: o\nruns: [{{task: Drill, agent: ppo, sweep: {_sw('every_task')}, "
     f"ablation: {_sw('search_sac')}}}]\n", "not a grid"),
    ("track: full\nheadroom: h\nout: o\nruns: [{task: Nope, agent: ppo, sweep: x.yaml}]\n", "runs[0].task"),
])
def test_bad_track_files_name_the_field(tmp_path, text, message):
    with pytest.raises(T.TrackError, match=None) as err:
        T.load_track(_write(tmp_path, text))
    assert message in str(err.value) and "\n" not in str(err.value)


def test_missing_results_name_the_command_and_run_lists_it(tmp_path, capsys):
    sweep = tmp_path / "s.yaml"
    sweep.write_text((ROOT / _sw("hammer_stiffness")).read_text()
                     .replace("out: experiments/hammer_stiffness", f"out: {tmp_path / 'out'}")
                     .replace("runs_dir: runs/results/hammer_stiffness", f"runs_dir: {tmp_path / 'runs'}"))
    f = _write(tmp_path, f"track: stiffness\nheadroom: docs/figures/headroom.json\nout: {tmp_path / 'o.md'}\n"
                         f"runs: [{{task: Hammer, agent: ppo, sweep: {sweep}}}]\n")
    assert T.main([str(f)]) == 2
    err = capsys.readouterr().err
    assert f"vswrist sweep {sweep}" in err and err.count("\n") == 1
    assert T.main([str(f), "--run", "--dry-run"]) == 0
    assert f"vswrist track: vswrist sweep {sweep}" in capsys.readouterr().out
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "sweep.json").write_text("{}")  # a sweep that started: --run resumes it
    _, runs = T.load_track(f)
    assert T.missing(runs) == [(f"vswrist sweep {sweep}", ["sweep", str(sweep), "--resume"])]
    assert not (tmp_path / "o.md").exists()
