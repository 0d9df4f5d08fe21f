"""tools.contribution: the stiffness contribution is the paired full - posture-only difference, seed by seed."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import stats

from vswrist_gym.tools.contribution import ContributionError, contribution


def _metrics(path, returns: dict):
    path.parent.mkdir(parents=True, exist_ok=True)
    eps = [{"seed": s, "episode": e, "reset_seed": 1_000_000 + 1000 * s + e, "return": r}
           for (s, e), r in returns.items()]
    path.write_text(json.dumps({"episodes": eps}))
    return path


def test_contribution_is_paired_per_seed_with_a_student_t_interval(tmp_path):
    rng = np.random.default_rng(0)
    base = {(s, e): float(rng.normal(-100, 30)) for s in range(4) for e in range(5)}
    offset = {0: 3.0, 1: 5.0, 2: 4.0, 3: 6.0}  # per-seed gain; the episode spread (30) cancels in the pairs
    full = {k: v + offset[k[0]] for k, v in base.items()}
    full[(9, 0)] = 0.0  # an episode without a partner is left out
    r = contribution(_metrics(tmp_path / "f.json", full), _metrics(tmp_path / "a.json", base))
    d = np.array(list(offset.values()))
    half = stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / np.sqrt(len(d))
    assert r["seeds"] == [0, 1, 2, 3] and r["episodes"] == 20
    assert r["contribution"]["mean"] == pytest.approx(d.mean())
    assert (r["contribution"]["low"], r["contribution"]["high"]) == pytest.approx((d.mean() - half, d.mean() + half))


def test_unpaired_or_broken_files_name_the_file(tmp_path):
    a = _metrics(tmp_path / "a.json", {(0, 0): 1.0})
    b = _metrics(tmp_path / "b.json", {(1, 0): 1.0})
    with pytest.raises(ContributionError, match="share no"):
        contribution(a, b)
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(ContributionError, match="bad.json"):
        contribution(tmp_path / "bad.json", a)
