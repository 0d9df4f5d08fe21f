"""Observation history through RL Zoo's `frame_stack` key: training stacks with SB3's VecFrameStack (outside the
normalisation, as rl_zoo3 does), and a trained run replays with the same stacking in evaluate, compare and sweeps.

Each test checks the stacking against an independent path: the unstacked environment on the same seed, or SB3's
own VecFrameStack driving the model."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from vswrist_gym.agents import hparams, protocol, runs
from vswrist_gym.agents.train import train

POLISH = "VSWrist/Polish-v1"
STIFFNESS_TRACK = {"action_mode": "residual", "residual": {"posture_scale": 0.0}}


def _entry(**extra) -> dict:
    return {"n_timesteps": 256, "n_envs": 2, "policy": "MlpPolicy",
            "normalize": {"norm_obs": True, "norm_reward": True},
            "n_steps": 64, "batch_size": 64, "n_epochs": 1, "eval_freq": 128, "n_eval_episodes": 2,
            "checkpoint_freq": 128, **extra}


def _write(tmp_path, env_id: str, entry: dict):
    path = tmp_path / "hp.yaml"
    path.write_text(yaml.safe_dump({env_id: entry}))
    return path


def test_frame_stack_key_is_read_and_checked():
    cfg = hparams.resolve_entry("ppo", "Pendulum-v1", {"n_timesteps": 10, "frame_stack": 4})
    assert cfg.frame_stack == 4 and "frame_stack" not in cfg.algo_kwargs
    assert hparams.resolve_entry("ppo", "Pendulum-v1", {"n_timesteps": 10}).frame_stack == 1
    for bad in (0, -2, 1.5, True, "4"):
        with pytest.raises(hparams.ConfigError, match="frame_stack"):
            hparams.resolve_entry("ppo", "Pendulum-v1", {"n_timesteps": 10, "frame_stack": bad})


def test_stacked_observation_is_the_unstacked_env_history():
    """World 0 of the stacked training env against `gym.make` on the same seed: the newest frame is last (SB3's
    convention for flat observations), the older ones are the previous observations, zeros before the episode."""
    import gymnasium as gym

    import vswrist_gym  # noqa: F401

    k = 3
    cfg = hparams.resolve_entry("ppo", POLISH, {"n_timesteps": 10, "n_envs": 2, "env_kwargs": STIFFNESS_TRACK,
                                                "frame_stack": k})
    venv = runs.wrap_frame_stack(runs.make_vec_env(cfg, 2, seed=5), cfg.frame_stack)
    env = gym.make(POLISH, **STIFFNESS_TRACK)
    try:
        width = env.observation_space.shape[0]
        assert venv.observation_space.shape == (k * width,)
        stacked = venv.reset()
        history = [np.zeros(width)] * (k - 1) + [env.reset(seed=5)[0]]
        rng = np.random.default_rng(0)
        for step in range(6):
            assert np.allclose(stacked[0], np.concatenate(history[-k:]), atol=1e-6), step
            action = rng.uniform(-1, 1, size=(2, *env.action_space.shape)).astype(np.float32)
            stacked, *_ = venv.step(action)
            history.append(env.step(action[0])[0])
    finally:
        venv.close()
        env.close()


def test_trained_agent_stacks_as_vecframestack_does(tmp_path):
    """A frame-stacked run (normalised, resumed once) replayed by TrainedAgent on raw observations chooses the
    actions the model chooses behind SB3's VecNormalize + VecFrameStack, through an automatic reset."""
    from stable_baselines3.common.vec_env import VecFrameStack

    path = _write(tmp_path, "Pendulum-v1", _entry(frame_stack=3, vec_env="dummy"))
    run = train("Pendulum-v1", "ppo", tmp_path / "run", config=path, seed=1, progress=False, log=lambda m: None)
    train("Pendulum-v1", "ppo", run, timesteps=384, resume=True, progress=False, log=lambda m: None)
    doc = yaml.safe_load((run / "config.yaml").read_text())
    assert doc["hyperparameters"]["frame_stack"] == 3  # the run records its stacking
    agent = runs.TrainedAgent(run)
    assert agent.frame_stack == 3 and agent.observation_shape == (3,)
    one_by_one = runs.TrainedAgent(run)  # world 0 alone, one observation at a time, no episode_start (vswrist video)

    venv = runs.make_vec_env(agent.cfg, 2, seed=11)
    normed = runs.load_vecnormalize(run, venv)
    normed.training, normed.norm_reward = False, False
    stacked_env = VecFrameStack(normed, 3)
    try:
        stacked = stacked_env.reset()
        raw = normed.get_original_obs()
        starts = np.ones(2, dtype=bool)
        resets = 0
        for _ in range(230):  # Pendulum ends at 200 steps: both worlds reset on the way
            want, _ = agent.model.predict(stacked, deterministic=True)
            got, _ = agent.predict(raw, episode_start=starts, deterministic=True)
            assert np.array_equal(got, want)
            if resets == 0:
                # a batch of one takes another BLAS path than a batch of two: equal to float32 rounding
                assert np.allclose(one_by_one.predict(raw[0], deterministic=True)[0], want[0], atol=1e-5)
            stacked, _, dones, _ = stacked_env.step(want)
            raw, starts = normed.get_original_obs(), dones
            resets += int(dones.sum())
        assert resets == 2
    finally:
        stacked_env.close()


def test_evaluate_replays_a_stacked_run_batched_and_one_by_one(tmp_path):
    """The protocol on a frame-stacked VS-Wrist run: the episodes of a seed run side by side in one batch give the
    records of the same episodes run one after another in a single env (each with its own history)."""
    path = _write(tmp_path, POLISH, _entry(frame_stack=2, env_kwargs=STIFFNESS_TRACK, n_timesteps=128,
                                           eval_freq=64, n_eval_episodes=1, checkpoint_freq=128))
    run = train(POLISH, "ppo", tmp_path / "run", config=path, seed=2, progress=False, log=lambda m: None)

    def make(env, a=runs.TrainedAgent(run)):
        a.check_env(env)
        return a

    kwargs = runs.TrainedAgent(run).cfg.env_kwargs
    batched, _ = protocol.evaluate(POLISH, make, [0], 2, env_kwargs=kwargs, batch=True)
    single, _ = protocol.evaluate(POLISH, make, [0], 2, env_kwargs=kwargs, batch=False)
    for a, b in zip(batched, single):
        assert a["reset_seed"] == b["reset_seed"]
        assert np.isclose(a["return"], b["return"], rtol=1e-6, atol=1e-6)
