"""The soak runner (vswrist_gym.tools.soak): a million steps with flat memory (slow), and its checks (fast)."""

import numpy as np
import pytest

from vswrist_gym import TASKS
from vswrist_gym.tools import soak

MIB = 1 << 20


@pytest.mark.slow
def test_a_million_steps_over_every_task_keep_memory_flat_and_warn_nothing():
    """Issue 13: 1,000,000 steps over every task with random and baseline actions (a quarter of them rebuilding
    the model at each reset), resident memory growth under 5 % after the warm-up, no warning, no NaN."""
    r = soak.run_soak(1_000_000, progress=False)
    print("\n" + soak.format_result(r))
    assert r.steps == 1_000_000
    assert {(c.task, c.agent) for c in r.cells} == {(t, a) for t in TASKS for a in soak.AGENTS}
    assert r.growth_pct < 5.0, soak.format_result(r)
    assert r.python_warnings == []
    assert r.mujoco_warnings == {}
    assert r.nan_obs == 0


def test_a_short_soak_covers_every_task_agent_and_setting_with_no_warning():
    """The code path of the soak, cheaply. Memory growth is not judged here: in 5,000 steps it is within the
    noise of allocator pools and first-use caches (the slow test measures it over a million steps)."""
    steps = 5000
    r = soak.run_soak(steps, progress=False)
    assert r.steps == steps == sum(c.steps for c in r.cells)
    pairs = {}
    for c in r.cells:
        assert c.steps == c.budget and c.episodes >= 1, c.label
        pairs.setdefault((c.task, c.agent), []).append(c)
    assert set(pairs) == {(t, a) for t in TASKS for a in soak.AGENTS}
    share = steps / len(pairs)
    for (task, agent), cells in pairs.items():
        assert abs(sum(c.steps for c in cells) - share) <= 1, (task, agent)  # even split over tasks x agents
        assert sorted(c.rebuild for c in cells) == [False, True], (task, agent)  # both settings run
    assert r.python_warnings == []
    assert r.mujoco_warnings == {}
    assert r.nan_obs == 0
    assert r.rss_warmup > 0 and r.rss_end > 0 and r.rss_samples[0][0] >= 0.05 * steps
    assert r.passed(max_growth=1e9)


def test_the_soak_counts_a_warning_and_a_non_finite_observation(monkeypatch):
    """The checks can fail: a warning raised by the agent, and NaN observations from the environment, are
    counted and fail the verdict."""
    from vswrist_gym.agents.analytic import AnalyticAgent
    from vswrist_gym.envs.base import VSWristEnv

    predict = AnalyticAgent.predict

    def warning_predict(self, *args, **kwargs):
        import warnings
        warnings.warn("soak test warning", UserWarning)
        return predict(self, *args, **kwargs)

    monkeypatch.setattr(AnalyticAgent, "predict", warning_predict)
    r = soak.run_soak(400, tasks=["LoadHold"], progress=False)
    baseline_steps = sum(c.steps for c in r.cells if c.agent == "baseline")
    assert len(r.python_warnings) == baseline_steps == 200
    assert set(r.python_warnings) == {"UserWarning: soak test warning"}
    assert not r.passed(max_growth=1e9)

    monkeypatch.setattr(AnalyticAgent, "predict", predict)
    observation = VSWristEnv._observation

    def nan_after_reset(self):
        obs = observation(self)
        if self._step >= 1:  # the reset's observation stays valid (Gymnasium's checker reads it)
            obs[0] = np.nan
        return obs

    monkeypatch.setattr(VSWristEnv, "_observation", nan_after_reset)
    r = soak.run_soak(400, tasks=["LoadHold"], progress=False)
    assert r.nan_obs == 400  # every step's observation
    assert not r.passed(max_growth=1e9)


def test_rss_follows_a_large_allocation():
    """The memory probe reads resident memory now: touching 64 MiB raises it by about that much."""
    import mmap

    # fresh anonymous pages, none resident until written: a NumPy array could reuse pages that the allocator kept
    # resident after an earlier test freed them, and then resident memory grows by less than the array
    def touch() -> int:
        block = mmap.mmap(-1, 64 * MIB)
        before = soak.rss_bytes()
        view = np.frombuffer(block, dtype=np.uint8)
        view[:] = 1  # writes every page
        grown = soak.rss_bytes() - before
        del view
        block.close()
        return grown

    # up to three tries: another thread of the test process may free memory during one of them
    grown = [touch() for _ in range(3)]
    assert any(60 * MIB <= g <= 80 * MIB for g in grown), [g / MIB for g in grown]


@pytest.mark.parametrize("kwargs, field", [({"steps": 0}, "steps"), ({"steps": 1.5}, "steps"),
                                           ({"tasks": ["Nope"]}, "tasks"), ({"tasks": []}, "tasks"),
                                           ({"warmup": 1.0}, "warmup"), ({"rebuild_fraction": -0.1}, "rebuild_fraction"),
                                           ({"rebuild_fraction": 1.5}, "rebuild_fraction"),
                                           ({"steps": 15}, "too few")])
def test_bad_soak_settings_fail_before_any_environment_is_built(kwargs, field, monkeypatch):
    monkeypatch.setattr(soak, "_build", lambda cell: pytest.fail("an environment was built"))
    with pytest.raises(ValueError, match=field):
        soak.run_soak(**{"steps": 1000, **kwargs}, progress=False)


def test_cli_rejects_bad_settings_in_one_line(capsys):
    assert soak.main(["--steps", "0", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("soak: error: steps must be") and "\n" not in err


@pytest.mark.parametrize("fraction, settings", [(0.0, [False]), (0.25, [False, True]), (1.0, [True])])
def test_the_rebuild_fraction_chooses_the_settings_and_keeps_the_even_split(fraction, settings):
    cells = soak._plan(1001, TASKS, fraction, seed=0)
    assert sorted({c.rebuild for c in cells}) == settings
    assert sum(c.budget for c in cells) == 1001
    rebuilt = sum(c.budget for c in cells if c.rebuild)
    assert abs(rebuilt - fraction * 1001) <= len(TASKS) * len(soak.AGENTS)  # rounding, at most 1 per pair
