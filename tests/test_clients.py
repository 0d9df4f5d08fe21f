"""What outside users meet with standard tools: one-line errors of `vswrist info` and `vswrist video` before any
work, intervals that stay in their metric's range, every trained agent's score beside the best constant on the
same episodes, the vector env's DISABLED autoreset and closed state, SB3 over an existing Gymnasium vector env,
and the exported wrist loaded by a Python that has MuJoCo and not this package."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
ID = "VSWrist/LoadHold-v0"
SHORT = {"episode_s": 0.2}  # 10 control steps: episodes end within a test


def vswrist(*args, timeout=300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONWARNINGS": "ignore::DeprecationWarning"}
    return subprocess.run([sys.executable, "-m", "vswrist_gym.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=env)


def one_line_error(res: subprocess.CompletedProcess, command: str) -> str:
    assert res.returncode == 2, res.stdout + res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"vswrist {command}: error: "), res.stderr
    return lines[0]


# ------------------------------------------------------------------------------------------------ info, video


def test_info_shows_the_environments_preset_and_names_it():
    import yaml

    from vswrist_gym.params import CONFIG_DIR

    env_preset = yaml.safe_load((CONFIG_DIR / "envs" / "defaults.yaml").read_text())["params"]
    res = vswrist("info")
    assert res.returncode == 0, res.stderr
    first = res.stdout.splitlines()[0]
    assert first == f"VS-Wrist parameter preset: {env_preset} (the environments' preset)"
    other = "paper" if env_preset != "paper" else "paper_knm"
    res = vswrist("info", "--params", other)
    assert res.stdout.splitlines()[0] == f"VS-Wrist parameter preset: {other} (the environments use {env_preset})"
    line = one_line_error(vswrist("info", "--params", "nope"), "info")
    assert "--params" in line and "'nope'" in line and "paper_knm" in line


@pytest.mark.parametrize("args, words", [
    (["--seed", "-1"], ["--seed", "4294967295"]),
    (["--width", "-5"], ["--width", "[16, 1280]"]),
    (["--height", "100000"], ["--height", "[16, 960]"]),
    (["--camera", "nope"], ["'nope'", "task_view"]),
])
def test_video_bad_input_is_one_line_and_writes_nothing(tmp_path, args, words):
    out = tmp_path / "v.mp4"
    line = one_line_error(vswrist("video", "--task", "LoadHold", "--out", out, *args), "video")
    assert all(w in line for w in words), line
    assert list(tmp_path.iterdir()) == []


def test_video_out_that_cannot_be_written_is_refused_before_rendering(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("keep")
    line = one_line_error(vswrist("video", "--task", "LoadHold", "--out", afile / "v.mp4"), "video")
    assert "--out" in line and "is a file" in line
    (tmp_path / "dir.mp4").mkdir()
    line = one_line_error(vswrist("video", "--task", "LoadHold", "--out", tmp_path / "dir.mp4"), "video")
    assert "is a folder" in line
    assert afile.read_text() == "keep"
    if os.geteuid() != 0:  # root writes into read-only folders
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        line = one_line_error(vswrist("video", "--task", "LoadHold", "--out", ro / "v.mp4"), "video")
        assert "not writable" in line


# ------------------------------------------------------------------------------------------------ intervals


def test_rate_interval_is_wilson_and_stays_in_the_unit_range():
    from vswrist_gym.agents.protocol import rate_ci, summarise

    # the Wilson score interval by its formula: (p + z^2/2n +- z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n)
    z = 1.959963984540054  # the normal 97.5 % quantile
    for k, n in ((3, 4), (0, 5), (5, 5), (1, 1), (7, 20)):
        p = k / n
        centre, half = p + z * z / (2 * n), z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
        ci = rate_ci([1.0] * k + [0.0] * (n - k))
        assert ci["low"] == pytest.approx((centre - half) / (1 + z * z / n), abs=1e-9)
        assert ci["high"] == pytest.approx((centre + half) / (1 + z * z / n), abs=1e-9)
        assert 0.0 <= ci["low"] <= p <= ci["high"] <= 1.0
    # two seeds with very different outcomes: a t interval over seeds would leave [0, 1] and go below 0 for an
    # RMS error; every interval stays inside the metric's range
    records = [{"seed": s, "episode": i, "return": -1.0, "success": float(s == 0 or i == 0),
                "rms_posture_error": 0.001 if s else 0.5, "peak_contact_force": 0.0, "rms_contact_force": 0.0,
                "elastic_energy": 0.1, "stiffness_used": 0.0, "length": 10.0, "impact_speed": math.nan}
               for s in (0, 1) for i in range(2)]
    summary = summarise(records)
    assert summary["success"]["mean"] == pytest.approx(0.75)
    assert 0.0 <= summary["success"]["low"] < 0.75 < summary["success"]["high"] <= 1.0
    assert summary["rms_posture_error"]["low"] == 0.0  # the t interval's lower end would be about -3.1
    assert summary["rms_posture_error"]["high"] > 0.5


# ------------------------------------------------------------------------------------------------ baselines


def test_evaluate_scores_a_shipped_agent_beside_the_best_constant(tmp_path):
    """The best constant is the fixed stiffness with the highest mean return on the agent's episodes, each
    constant run here on its own (one env, episode after episode, not the batch `evaluate` uses), on the task
    as `vswrist compare` and the shipped cards run the analytic agent (its own action mode)."""
    import gymnasium as gym

    from vswrist_gym.agents.analytic import AnalyticAgent
    from vswrist_gym.agents.baseline import DEFAULT_STIFFNESS_LEVELS
    from vswrist_gym.agents.protocol import reset_seed, run_episode

    res = vswrist("evaluate", "--task", "VSWrist/Hammer-v1", "--agent", "pretrained:Hammer", "--episodes", "2",
                  "--seeds", "3", "--out", tmp_path / "agent")
    assert res.returncode == 0, res.stderr
    doc = json.loads((tmp_path / "agent" / "metrics.json").read_text())
    base = doc["baseline"]
    env = gym.make(doc["task"])
    returns = {k: [run_episode(env, AnalyticAgent(env, stiffness=k), reset_seed(3, i))[0]["return"] for i in (0, 1)]
               for k in DEFAULT_STIFFNESS_LEVELS}
    env.close()
    best = max(returns, key=lambda k: np.mean(returns[k]))
    assert base["stiffness"] == best and base["return"]["mean"] == pytest.approx(np.mean(returns[best]), rel=1e-9)
    # the paired difference, episode by episode against the agent's own returns
    agent = {e["episode"]: e["return"] for e in doc["episodes"]}
    diffs = [agent[i] - returns[best][i] for i in (0, 1)]
    assert base["paired_difference_return"]["mean"] == pytest.approx(np.mean(diffs), rel=1e-9, abs=1e-9)
    assert base["paired_difference_return"]["n"] == 2
    assert "best constant stiffness on the same episodes: analytic:" in res.stdout
    assert "paired difference in return" in res.stdout
    res = vswrist("evaluate", "--task", "VSWrist/Hammer-v1", "--agent", "pretrained:Hammer", "--episodes", "1",
                  "--seeds", "3", "--out", tmp_path / "plain", "--no-baseline")
    assert res.returncode == 0 and "best constant" not in res.stdout
    assert "baseline" not in json.loads((tmp_path / "plain" / "metrics.json").read_text())


def test_video_shows_the_best_constant_of_the_same_episode(tmp_path):
    res = vswrist("video", "--task", "VSWrist/Hammer-v1", "--agent", "pretrained:Hammer", "--seed", "4",
                  "--width", "64", "--height", "48", "--out", tmp_path / "v.mp4")
    assert res.returncode == 0, res.stderr
    import re

    agent = float(re.search(r"return (-?[\d.]+),", res.stdout).group(1))
    m = re.search(r"best constant stiffness on the same episode: analytic:([-+.\d]+), return (-?[\d.]+); "
                  r"difference \(agent - best constant\) ([-+.\d]+)", res.stdout)
    assert m, res.stdout
    assert float(m.group(3)) == pytest.approx(agent - float(m.group(2)), abs=0.011)
    assert (tmp_path / "v.mp4").stat().st_size > 0 and not list(tmp_path.glob(".*partial*"))


# ------------------------------------------------------------------------------------------------ vector env


def _zeros(env):
    return np.zeros((env.num_envs, *env.single_action_space.shape))


def test_disabled_autoreset_steps_as_next_step_then_waits_for_a_reset():
    import gymnasium as gym
    from gymnasium.vector import AutoresetMode

    import vswrist_gym  # noqa: F401
    from gymnasium.error import ResetNeeded

    off = gym.make_vec(ID, 2, vectorization_mode="vector_entry_point", autoreset_mode=AutoresetMode.DISABLED,
                       config=SHORT)
    ref = gym.make_vec(ID, 2, vectorization_mode="vector_entry_point", config=SHORT)
    rng = np.random.default_rng(0)
    a, b = off.reset(seed=3)[0], ref.reset(seed=3)[0]
    np.testing.assert_array_equal(a, b)
    done = np.zeros(2, dtype=bool)
    while not done.any():
        act = rng.uniform(-1, 1, size=(2, *off.single_action_space.shape))
        a, ra, ta, ua, _ = off.step(act)
        b, rb, tb, ub, _ = ref.step(act)
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(ra, rb)
        done = ta | ua
    with pytest.raises(ResetNeeded, match="DISABLED"):
        off.step(_zeros(off))
    first, _ = off.reset(seed=[11, 12], options={"reset_mask": done})
    single = gym.make(ID, config=SHORT)
    np.testing.assert_array_equal(first[0], single.reset(seed=11)[0])  # world 0 restarted as asked
    off.step(_zeros(off))
    off.close()
    from gymnasium.error import ClosedEnvironmentError

    with pytest.raises(ClosedEnvironmentError):
        off.step(_zeros(off))
    with pytest.raises(ClosedEnvironmentError):
        off.reset(seed=0)
    ref.close()
    single.close()


@pytest.mark.parametrize("mode, autoreset", [("sync", "NEXT_STEP"), ("sync", "SAME_STEP"),
                                             ("vector_entry_point", "DISABLED"),
                                             ("vector_entry_point", "NEXT_STEP")])
def test_sb3_adapter_over_a_gymnasium_vector_env_matches_the_batch_vecenv(mode, autoreset):
    """SB3's view (same-step resets, terminal_observation, TimeLimit.truncated) of any vector env equals that of
    BatchVecEnv, built on the batch with SAME_STEP autoresets, on the same seeds and actions."""
    import gymnasium as gym
    from gymnasium.vector import AutoresetMode

    from vswrist_gym.agents.vec_env import BatchVecEnv

    ar = AutoresetMode[autoreset]
    if mode == "sync":
        envs = gym.make_vec(ID, 2, vectorization_mode="sync", vector_kwargs={"autoreset_mode": ar}, config=SHORT)
    else:
        envs = gym.make_vec(ID, 2, vectorization_mode=mode, autoreset_mode=ar, config=SHORT)
    ours, ref = BatchVecEnv.from_vector_env(envs), BatchVecEnv(ID, 2, {"config": SHORT})
    ours.seed(5)
    ref.seed(5)
    np.testing.assert_array_equal(ours.reset(), ref.reset())
    rng = np.random.default_rng(1)
    ends = 0
    for _ in range(25):  # two and a half episodes
        act = rng.uniform(-1, 1, size=(2, *ref.action_space.shape)).astype(np.float32)
        ours.step_async(act)
        ref.step_async(act)
        o1, r1, d1, i1 = ours.step_wait()
        o2, r2, d2, i2 = ref.step_wait()
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(d1, d2)
        for a, b, d in zip(i1, i2, d1):
            assert a["TimeLimit.truncated"] == b["TimeLimit.truncated"]
            if d:
                ends += 1
                np.testing.assert_array_equal(a["terminal_observation"], b["terminal_observation"])
    assert ends >= 4
    ours.close()
    ref.close()


def test_ppo_trains_on_an_existing_make_vec_env():
    import gymnasium as gym
    from stable_baselines3 import PPO

    from vswrist_gym.agents.vec_env import BatchVecEnv

    envs = gym.make_vec(ID, 2, vectorization_mode="vector_entry_point", config=SHORT)
    with pytest.raises(TypeError, match="VectorEnv"):
        BatchVecEnv.from_vector_env(gym.make(ID))
    model = PPO("MlpPolicy", BatchVecEnv.from_vector_env(envs), n_steps=32, batch_size=32, n_epochs=1,
                device="cpu", seed=0).learn(64)
    assert model.num_timesteps == 64
    model.get_env().close()


# ------------------------------------------------------------------------------------------------ export bundle


def _mujoco_only_site(tmp_path: Path) -> Path:
    """A folder holding mujoco and the packages it imports (links into this environment), and no
    vswrist_gym, nor any distribution metadata (so no mujoco.plugins entry point): what `pip install mujoco`
    gives a fresh environment."""
    import mujoco

    probe = subprocess.run([sys.executable, "-c", "import sys, mujoco; print('\\n'.join(sorted({m.split('.')[0] "
                            "for m in sys.modules if getattr(sys.modules[m], '__file__', None)})))"],
                           capture_output=True, text=True, env={**os.environ, "VSWRIST_NATIVE": "0"}, check=True)
    site = tmp_path / "site"
    site.mkdir()
    home = Path(mujoco.__file__).resolve().parents[1]
    for name in probe.stdout.split():
        for cand in (home / name, home / f"{name}.py"):
            if cand.exists() and name != "vswrist_gym":
                (site / cand.name).symlink_to(cand)
    for lib in home.glob("*.libs"):  # the wheels' vendored shared libraries (numpy.libs, ...)
        (site / lib.name).symlink_to(lib)
    return site


def test_bundle_loads_in_a_python_with_mujoco_and_not_vswrist_gym(tmp_path):
    from vswrist_gym.model.export import BUNDLE_LIBRARY

    bundle = tmp_path / "bundle"
    res = vswrist("export", "--params", "paper_knm", "--bundle", bundle)
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in bundle.iterdir()) == sorted(["wrist.xml", "README.md", BUNDLE_LIBRARY])
    xml = (bundle / "wrist.xml").read_text()
    assert xml.startswith("<!--") and BUNDLE_LIBRARY in xml.split("-->")[0]
    readme = (bundle / "README.md").read_text()
    assert "mj_loadPluginLibrary" in readme and "simulate" in readme and "plugin/" in readme
    site = _mujoco_only_site(tmp_path)
    code = (f"import sys; sys.path.insert(0, {str(site)!r})\n"
            "import importlib.util, mujoco\n"
            "assert importlib.util.find_spec('vswrist_gym') is None\n"
            "try:\n"
            "    mujoco.MjModel.from_xml_path('wrist.xml'); print('loaded without the library')\n"
            "except ValueError as e:\n"
            "    print('refused:', str(e).splitlines()[0])\n"
            f"mujoco.mj_loadPluginLibrary('./{BUNDLE_LIBRARY}')\n"
            "m = mujoco.MjModel.from_xml_path('wrist.xml'); d = mujoco.MjData(m)\n"
            "mujoco.mj_resetDataKeyframe(m, d, m.key('home_stiff').id)\n"
            "q0 = d.qpos.copy(); mujoco.mj_step(m, d, 200)\n"
            "print('plugins', m.nplugin, 'drift', float(abs(d.qpos - q0).max()),\n"
            "      'force', float(abs(d.qfrc_passive).max()))\n")
    # -S: no site-packages (and no .pth files: not the editable install either); -E: no PYTHON* variables
    res = subprocess.run([sys.executable, "-S", "-E", "-c", code], capture_output=True, text=True, cwd=bundle,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert lines[0].startswith("refused:") and "vswrist.drive" in lines[0]
    words = lines[1].split()
    assert words[1] == "5"  # drives A, B, C, ps and the closure monitor
    # the preloaded springs act (passive torques of newton-metres) and hold the wrist at its keyframe
    assert float(words[5]) > 0.1 and float(words[3]) < 0.05, lines[1]


def test_export_overwrites_only_with_force(tmp_path):
    out = tmp_path / "w.xml"
    out.write_text("mine")
    res = vswrist("export", "--out", out)
    assert res.returncode == 2 and "--force" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert out.read_text() == "mine"
    assert vswrist("export", "--out", out, "--force").returncode == 0
    assert out.read_text().startswith("<!--") and "<mujoco" in out.read_text()
    bundle = tmp_path / "b"
    assert vswrist("export", "--bundle", bundle).returncode == 0
    before = (bundle / "wrist.xml").read_bytes()
    res = vswrist("export", "--bundle", bundle, "--params", "paper_knm")
    assert res.returncode == 2 and "--force" in res.stderr
    assert (bundle / "wrist.xml").read_bytes() == before
    assert vswrist("export", "--bundle", bundle, "--params", "paper_knm", "--force").returncode == 0
    assert (bundle / "wrist.xml").read_bytes() != before
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("x")
    res = vswrist("export", "--bundle", tmp_path / "other", "--force")
    assert res.returncode == 2 and "notes.txt" in res.stderr
