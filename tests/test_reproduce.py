"""`vswrist reproduce --quick`: the pipeline runs end to end and its numbers obey independent physical facts."""

import json
import math

import numpy as np
import pytest

from vswrist_gym.tools.reproduce import main


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce")
    assert main(["--out", str(out), "--quick"]) == 0
    return out, json.loads((out / "results.json").read_text())


def test_results_hold_every_key_beside_the_papers_numbers(results):
    out, r = results
    assert r["paper_reported"] == {"rms_error_ls": 0.15, "rms_error_hs": 0.007,
                                   "rms_torque_ls": 0.07, "rms_torque_hs": 1.72}
    for preset in ("paper", "paper_knm", "paper_identified"):
        for key in ("rms_error_ls", "rms_error_hs", "rms_torque_ls", "rms_torque_hs"):
            assert math.isfinite(r[preset][key]) and r[preset][key] >= 0
    assert set(r["criteria"]) >= {"error_ratio_ls_over_hs", "torque_ratio_hs_over_ls", "passed"}
    assert "gravity" in r["choices"] and "trajectory" in r["choices"]
    for name in r["figures"]:
        png = out / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size < 300_000


def test_stiffer_preload_means_larger_elastic_torque_and_stiffness(results):
    _, r = results
    for preset in ("paper", "paper_knm"):
        assert r[preset]["rms_torque_hs"] > r[preset]["rms_torque_ls"]
        assert min(r[preset]["stiffness_eig_hs"]) > max(r[preset]["stiffness_eig_ls"])


def test_small_disturbance_scenario_shows_the_papers_torque_levels(results):
    """With the small load the paper's numbers imply, the springs carry about their preload: per leg
    0.07 N m (LS) and 1.72 N m (HS), the paper's RMS torques, and the soft wrist deflects more."""
    _, r = results
    d = r["paper_implied_load"]
    assert d["rms_torque_ls"] == pytest.approx(0.07, rel=0.15)
    assert d["rms_torque_hs"] == pytest.approx(1.72, rel=0.05)
    assert d["rms_error_ls"] > 3 * d["rms_error_hs"]
    assert np.isfinite(d["error_ratio_ls_over_hs"])


def test_identified_preset_beside_paper_under_both_load_readings(results):
    """The identified motors differ from `paper`'s only in dynamics: under the implied load the elastic
    torques stay at the preload (as for `paper`), and the faster motors track the HS trial more closely."""
    _, r = results
    ident, paper = r["paper_identified_implied_load"], r["paper_implied_load"]
    assert ident["rms_torque_ls"] == pytest.approx(0.07, rel=0.15)
    assert ident["rms_torque_hs"] == pytest.approx(1.72, rel=0.05)
    assert ident["rms_error_hs"] < paper["rms_error_hs"]
    assert "fig_rms_against_paper.png" in r["figures"]
    assert "fig3c_implied_load_paper_identified.png" in r["figures"]


def test_forearm_vertical_orientation(results):
    """Forearm vertical, the 1.5 kg load along the hand axis. Hand down: at the centre the load has no lever,
    off it the load pulls the hand back (a pendulum, m g L = 1.75 N m/rad, more than the LS coupler's 0.09),
    so both trials stay bounded and HS tracks better than LS. Hand up: an inverted pendulum stronger than the
    LS coupler, which falls over (errors of radians)."""
    _, r = results
    for preset in ("paper", "paper_identified"):
        down, up = r["forearm_vertical"][preset]["hand_down"], r["forearm_vertical"][preset]["hand_up"]
        assert down["gravity"][0] > 0 > up["gravity"][0]
        assert down["rms_error_hs"] < down["rms_error_ls"] < 0.5
        assert up["max_error_ls"] > 1.0
