"""The validity gate (vswrist_gym/tools/gate.py): selection reads tuning episodes only, the paired statistics and
the pass rules against hand computations, and a short smoke run of the headroom path. No training here."""

import json
import math

import numpy as np
import pytest

from vswrist_gym.agents.protocol import HELDOUT_EVAL_SEEDS, TUNING_EVAL_SEEDS, reset_seed
from vswrist_gym.tools import gate

# ------------------------------------------------------------------------------------------------ selection


def _tagged(monkeypatch):
    """Constant and rule agents replaced by tags, so that a fake runner knows which agent it is asked for."""
    monkeypatch.setattr(gate, "constant_agent", lambda c: ("constant", c))
    monkeypatch.setattr(gate, "rule_agent", lambda lv: ("rule", tuple(lv)))


def test_selection_reads_only_tuning_seeds_and_picks_the_highest_mean(monkeypatch):
    _tagged(monkeypatch)
    seen = []

    def runner(env_id, agent, seeds, episodes, kwargs):
        seen.extend(seeds)
        kind, x = agent
        if kind == "constant":   # a parabola whose top is at +0.5
            return [-(x - 0.5) ** 2 + 0.01 * i for i in range(len(seeds) * episodes)]
        return [10.0 if x == (-0.5, 1.0) else 0.0] * (len(seeds) * episodes)

    sel = gate.select("VSWrist/LoadHold-v0", runner=runner)
    assert seen and set(seen) <= set(TUNING_EVAL_SEEDS)
    assert not set(seen) & set(HELDOUT_EVAL_SEEDS)
    assert sel["best_constant"] == 0.5
    assert sel["rule_levels"] == [-0.5, 1.0]
    # every constant of the analytic baseline and every soft < stiff pair of them was tried
    assert len(sel["constants"]) == 5 and len(sel["rules"]) == 10


@pytest.mark.parametrize("seeds", [HELDOUT_EVAL_SEEDS, [TUNING_EVAL_SEEDS[0], HELDOUT_EVAL_SEEDS[0]], [0], []])
def test_selection_refuses_any_other_seed_before_running(monkeypatch, seeds):
    _tagged(monkeypatch)

    def runner(*args):
        raise AssertionError("an episode ran")

    with pytest.raises(gate.GateError, match="tuning evaluation seeds"):
        gate.select("VSWrist/LoadHold-v0", seeds=seeds, runner=runner)


def test_report_refuses_tuning_seeds(monkeypatch):
    _tagged(monkeypatch)
    with pytest.raises(gate.GateError, match="held-out evaluation seeds"):
        gate.headroom("VSWrist/LoadHold-v0", {"best_constant": 0.0, "rule_levels": [-1.0, 1.0]},
                      seeds=TUNING_EVAL_SEEDS, runner=lambda *a: [0.0])


def test_the_seed_ranges_do_not_overlap():
    tune = {reset_seed(s, i) for s in TUNING_EVAL_SEEDS for i in range(gate.EPISODES_PER_SEED)}
    held = {reset_seed(s, i) for s in HELDOUT_EVAL_SEEDS for i in range(gate.EPISODES_PER_SEED)}
    assert len(tune) == len(held) == 100 and not tune & held


# ------------------------------------------------------------------------------------------------ statistics


def test_paired_statistics_by_hand():
    # d = [2, 3, 2, 3]: mean 2.5, sample variance (4 x 0.25) / 3 = 1/3, s.e. sqrt(1/3) / 2
    out = gate.paired([3.0, 5.0, 4.0, 6.0], [1.0, 2.0, 2.0, 3.0])
    assert out["mean"] == pytest.approx(2.5)
    assert out["se"] == pytest.approx(math.sqrt(1.0 / 3.0) / 2.0)
    assert out["n"] == 4 and out["wins"] == 1.0
    # pairing removes what the episodes share: a common offset per episode leaves the difference unchanged
    base = np.array([100.0, -50.0, 7.0, 0.0])
    again = gate.paired(base + [3.0, 5.0, 4.0, 6.0], base + [1.0, 2.0, 2.0, 3.0])
    assert again["mean"] == pytest.approx(2.5) and again["se"] == pytest.approx(out["se"])


def test_paired_refuses_unequal_or_too_short_lists():
    with pytest.raises(gate.GateError, match="equal-length"):
        gate.paired([1.0, 2.0], [1.0, 2.0, 3.0])
    with pytest.raises(gate.GateError, match="at least 2"):
        gate.paired([1.0], [0.0])


@pytest.mark.parametrize("mean,se,passes", [(5.0, 1.0, True), (4.99, 1.0, False), (50.0, 9.9, True),
                                            (1.0, 0.0, True), (-10.0, 0.0, False), (-10.0, 1.0, False),
                                            (0.0, 0.0, False)])
def test_headroom_rule(mean, se, passes):
    assert gate.headroom_passes({"mean": mean, "se": se}) is passes


def test_share_interval_by_hand():
    # shares 0.1, 0.2, 0.3: mean 0.2, s.d. 0.1, t(0.975, df 2) = 4.3027 (Student's table): half 0.2484
    sh = gate.share_interval([1.0, 2.0, 3.0], 10.0)
    assert sh["shares"] == pytest.approx([0.1, 0.2, 0.3])
    assert sh["mean"] == pytest.approx(0.2)
    assert sh["high"] == pytest.approx(0.2 + 4.3027 * 0.1 / math.sqrt(3), abs=1e-4)
    assert sh["low"] == pytest.approx(0.2 - 4.3027 * 0.1 / math.sqrt(3), abs=1e-4)
    assert gate.necessity_passes(sh)          # upper end 0.448 < 0.5
    # shares 0.1, 0.2, 0.4: s.d. 0.1528, upper end 0.233 + 4.3027 x 0.1528 / sqrt 3 = 0.613 >= 0.5
    wide = gate.share_interval([1.0, 2.0, 4.0], 10.0)
    assert wide["high"] == pytest.approx(0.7 / 3 + 4.3027 * 0.152753 / math.sqrt(3), abs=1e-3)
    assert not gate.necessity_passes(wide)


def test_necessity_needs_headroom_and_two_seeds():
    assert math.isnan(gate.share_interval([1.0, 2.0], 0.0)["mean"])
    assert not gate.necessity_passes(gate.share_interval([1.0, 2.0], -3.0))
    assert not gate.necessity_passes(gate.share_interval([0.0], 10.0))
    # a posture trim that loses to the constant recovers none of the headroom: passes
    assert gate.necessity_passes(gate.share_interval([-5.0, -4.0, -6.0], 10.0))


def _doc(rule_gain: float, ppo_gains, noise: float = 1.0, feedback_gain: float = 0.0) -> dict:
    """A result document with 100 synthetic held-out episodes."""
    rng = np.random.default_rng(0)
    const = list(rng.normal(-100.0, 20.0, 100))
    rule = [c + rule_gain + noise * e for c, e in zip(const, rng.standard_normal(100))]
    doc = {"task": "VSWrist/Fake-v0", "selection": {"best_constant": 0.5, "rule_levels": [-1.0, 1.0]},
           "headroom": {"returns": {"constant": {"+0.5": const}, "rule": rule}}}
    d = gate.paired(rule, const)
    doc["headroom"].update(rule_minus_constant=d, z=d["mean"] / d["se"], passes=gate.headroom_passes(d))
    doc["necessity"] = {"seeds": [0, 1, 2], "runs": {str(k): {"returns": [c + g for c in const]}
                                                     for k, g in enumerate(ppo_gains)}}
    doc["necessity"]["summary"] = gate.necessity_summary(doc)
    fb = [c + feedback_gain + noise * e for c, e in zip(const, rng.standard_normal(100))]
    doc["feedback"] = {"k": 2.0, "returns": fb, **gate.feedback_verdict(gate.paired(fb, const), d["mean"])}
    return doc


def test_gate_verdicts_on_synthetic_results():
    good = _doc(10.0, [1.0, 2.0, 3.0])        # headroom z ~ 100; shares 0.1-0.3
    assert good["headroom"]["passes"] and good["necessity"]["summary"]["passes"]
    assert gate.gate_row(good).endswith("| **pass** |")
    posture = _doc(10.0, [6.0, 7.0, 8.0])     # the posture trim recovers 70 % of it
    assert not posture["necessity"]["summary"]["passes"]
    assert gate.gate_row(posture).endswith("| fail |")
    flat = _doc(0.05, [0.0, 0.0, 0.0])        # no headroom beyond 5 s.e.
    assert not flat["headroom"]["passes"] and gate.gate_row(flat).endswith("| fail |")
    partial = _doc(10.0, [1.0])               # one training seed of three: no verdict yet
    assert not partial["necessity"]["summary"]["complete"] and gate.gate_row(partial).endswith("| pending |")
    # the learner finds no posture substitute, a hand-written posture feedback recovers 80 % of the headroom
    fed = _doc(10.0, [1.0, 2.0, 3.0], feedback_gain=8.0)
    assert fed["necessity"]["summary"]["passes"] and not fed["feedback"]["passes"] and not gate.passes(fed)
    assert gate.gate_row(fed).endswith("| fail |")
    assert gate.passes(good)
    # the feedback's share interval: gain 4 +- 1.96 s.e. (0.1 for noise 1 over 100 episodes) over a headroom of 10
    near = _doc(10.0, [1.0, 2.0, 3.0], feedback_gain=4.0)
    sh, g, h = near["feedback"]["share"], near["feedback"]["gain"], near["headroom"]["rule_minus_constant"]["mean"]
    assert sh["high"] == pytest.approx((g["mean"] + 1.959964 * g["se"]) / h, rel=1e-6) and near["feedback"]["passes"]
    unmeasured = _doc(10.0, [1.0, 2.0, 3.0])
    del unmeasured["feedback"]
    assert gate.gate_row(unmeasured).endswith("| pending |") and not gate.passes(unmeasured)


def test_a_result_made_under_another_protocol_is_refused(tmp_path):
    path = gate.result_path(tmp_path, "VSWrist/LoadHold-v0")
    path.write_text(json.dumps({"task": "VSWrist/LoadHold-v0", "protocol": gate.protocol_block(budget=1000)}))
    with pytest.raises(gate.GateError, match="another protocol"):
        gate.run_task("VSWrist/LoadHold-v0", tmp_path, tmp_path / "runs", stage="headroom")


# ------------------------------------------------------------------------------------------------ necessity entry


@pytest.mark.parametrize("env_id", ["VSWrist/LoadHold-v0", "VSWrist/Hammer-v0"])
def test_posture_only_entry_holds_the_stiffness_at_the_constant(env_id):
    from vswrist_gym.agents.hparams import resolve_entry, track_of

    doc = gate.posture_only_entry(env_id, -0.5, budget=1234)
    entry = doc[env_id]
    cfg = resolve_entry("ppo", env_id, {**entry, **doc["vswrist"][env_id]})
    assert cfg.n_timesteps == 1234
    assert cfg.env_kwargs["residual"] == {"posture_scale": 0.15, "stiffness_scale": 0.0, "stiffness_nominal": -0.5}
    assert track_of(cfg.env_kwargs) == "full"


class _Zero:
    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.zeros(4, dtype=np.float32), None


def test_a_zero_posture_trim_is_the_constant_on_the_same_episodes():
    """What makes necessity's pairing valid: the posture-only policy's action space at zero is the selected
    constant's reference agent, and the same reset seed gives the same episode in both action modes."""
    short = {"episode_s": 0.3}
    seeds = HELDOUT_EVAL_SEEDS[:1]
    a = gate.episode_returns("VSWrist/LoadHold-v0", gate.constant_agent(0.5), seeds, 2, {"config": short})
    b = gate.episode_returns("VSWrist/LoadHold-v0", lambda env: _Zero(), seeds, 2,
                             {"config": short, "action_mode": "residual",
                              "residual": {"posture_scale": 0.15, "stiffness_scale": 0.0, "stiffness_nominal": 0.5}})
    assert a != pytest.approx([0.0, 0.0], abs=1e-3)
    assert b == pytest.approx(a, abs=0.05)


def test_headroom_path_smoke():
    """The real selection and report on short episodes (2 per seed, one seed each)."""
    short = {"episode_s": 0.3}
    sel = gate.select("VSWrist/LoadHold-v0", seeds=TUNING_EVAL_SEEDS[:1], episodes=2, config=short)
    assert sel["best_constant"] in gate.CONSTANT_COMMANDS
    assert max(sel["constants"].values()) == sel["constants"][f"{sel['best_constant']:+.1f}"]
    hr = gate.headroom("VSWrist/LoadHold-v0", sel, seeds=HELDOUT_EVAL_SEEDS[:1], episodes=2, config=short)
    assert hr["reset_seeds"] == [reset_seed(HELDOUT_EVAL_SEEDS[0], 0), reset_seed(HELDOUT_EVAL_SEEDS[0], 1)]
    best = hr["returns"]["constant"][f"{sel['best_constant']:+.1f}"]
    assert len(best) == len(hr["returns"]["rule"]) == 2
    d = np.subtract(hr["returns"]["rule"], best)
    assert hr["rule_minus_constant"]["mean"] == pytest.approx(d.mean())
    assert hr["passes"] == (d.mean() > 0 and d.mean() >= 5 * abs(d[0] - d[1]) / 2)  # s.e. of 2 values: |d0-d1|/2
    fb = gate.feedback("VSWrist/LoadHold-v0", sel, best, hr["rule_minus_constant"]["mean"], gains=(0.0, 2.0),
                       tuning=TUNING_EVAL_SEEDS[:1], heldout=HELDOUT_EVAL_SEEDS[:1], episodes=2,
                       runner=lambda env_id, make, seeds, episodes, kw: gate.episode_returns(
                           env_id, make, seeds, episodes, {**kw, "config": {**kw["config"], **short}}))
    assert fb["k"] in (0.0, 2.0) and len(fb["returns"]) == 2
    if fb["k"] == 0.0:  # no trim: the constant's episodes again (the zero residual is the reference agent)
        assert fb["returns"] == pytest.approx(best, abs=0.05)


# ------------------------------------------------------------------------------------------------ v1 tasks


@pytest.mark.parametrize("task,cue", [("LoadHold", "load_cue"), ("Drill", "engage_cue")])
def test_v1_is_v0_with_the_cue_added_to_the_observation(task, cue):
    """The same seed and actions give v0's observation, rewards and info in v1, plus the cue, which turns on
    cue_lead_s before the hidden onset (LoadHold: the load stays; Drill: off again when the drill releases)."""
    import gymnasium as gym

    import vswrist_gym

    assert f"VSWrist/{task}-v1" in vswrist_gym.ENV_IDS
    e0, e1 = gym.make(f"VSWrist/{task}-v0"), gym.make(f"VSWrist/{task}-v1")
    u0, u1 = e0.unwrapped, e1.unwrapped
    assert (u0.task_id, u1.task_id) == (f"VSWrist/{task}-v0", f"VSWrist/{task}-v1")
    assert cue not in u0.obs_slices and list(u1.obs_slices)[-1] == cue
    assert u1.obs_size == u0.obs_size + 1
    rng = np.random.default_rng(7)
    for seed in (5, 6):
        o0, _ = e0.reset(seed=seed)
        o1, _ = e1.reset(seed=seed)
        np.testing.assert_array_equal(o1[:-1], o0)
        if task == "LoadHold":
            on, off = u1.load_info()["onset"] - u1.cue_lead_s, math.inf
        else:
            on, off = u1._t_on - u1.cue_lead_s, u1._t_off
        cues, times = [o1[-1]], [0.0]
        done = False
        while not done:
            a = rng.uniform(-1.0, 1.0, e0.action_space.shape).astype(np.float32)
            o0, r0, t0, tr0, i0 = e0.step(a)
            o1, r1, t1, tr1, i1 = e1.step(a)
            np.testing.assert_array_equal(o1[:-1], o0)
            assert (r1, t1, tr1) == (r0, t0, tr0)
            assert i1["posture_error"] == i0["posture_error"] and i1["elastic_energy"] == i0["elastic_energy"]
            cues.append(o1[-1])
            times.append(i1["time"])
            done = t0 or tr0
        want = [1.0 if on - 1e-9 <= t < off else 0.0 for t in times]
        assert cues == want
        assert 0.0 < sum(want) < len(want)   # the cue turns on within the episode
    e0.close()
    e1.close()
