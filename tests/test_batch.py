"""The batched core (``gym.make_vec(id, N)``) against the single environments, and its vector API."""

import pickle
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import vswrist_gym
from vswrist_gym.agents.analytic import AnalyticAgent

sys.path.insert(0, str(Path(__file__).parent / "reference"))
import record  # noqa: E402  (tests/reference/record.py: the recorded protocol)

IDS = list(vswrist_gym.ENV_IDS)
N = 3
STEPS = 70
DIVERGE = (1, 40)  # (world, step): poison world 1's velocities before step 40, in the batch and its single twin


def make_batch(env_id, n=N, **kw):
    return gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kw)


def _compare_info(single: dict, vec: dict, i: int, where: str) -> None:
    for k, v in single.items():
        if isinstance(v, (bool, int, float, np.number, np.ndarray)):
            assert vec[f"_{k}"][i], f"{where}: info[{k!r}] missing for world {i}"
            np.testing.assert_allclose(vec[k][i], v, rtol=0, atol=1e-9, err_msg=f"{where}: info[{k!r}]")
        elif isinstance(v, str):
            assert vec[k][i] == v, where


@pytest.mark.parametrize("latency", [True, False], ids=["latency", "compiled"])
@pytest.mark.parametrize("policy", ["random", "analytic"])
@pytest.mark.parametrize("env_id", IDS)
def test_batched_world_i_is_the_single_env_with_seed_s_plus_i(env_id, policy, latency):
    """World i of the batch reproduces gym.make(id) reset with seed s + i, step for step, through short episodes
    (autoresets) and a divergence in one world; physics on 2 threads, through the compiled advance
    (``model.advance_lib``; with latency randomisation, each period's first substeps on the previous motor
    references), with each chunk's rewards and observations computed while later chunks' physics runs; a task
    that steps some periods itself (Throw: substep by substep near the release) is advanced world by world in
    those periods (``tests/test_throw.py`` follows whole throws)."""
    # episodes of 25 control steps (Hammer and Throw run at 100 Hz), so that every world resets several times
    cfg = {"episode_s": 0.25 if env_id.startswith(("VSWrist/Hammer", "VSWrist/Throw")) else 0.5,
           "randomize": {"latency": {"enabled": latency}}}
    for seed in (2, 9):
        venv = make_batch(env_id, config=cfg, threads=2)
        from vswrist_gym.envs.base import VSWristEnv
        from vswrist_gym.envs.shared import PeriodMeanForce
        from vswrist_gym.model import advance_lib

        from vswrist_gym.envs.hooks import over_arrays

        cls = type(venv.unwrapped.envs[0])
        own = cls._advance_physics not in (VSWristEnv._advance_physics, PeriodMeanForce._advance_physics)
        watched = own and over_arrays(cls, "_watch_worlds")  # Throw: its release search runs in the compiled watch
        assert (venv.unwrapped.batch_sim.lib is not None) == (advance_lib.load() is not None and (not own or watched))
        singles = [gym.make(env_id, config=cfg) for _ in range(N)]
        rng = np.random.default_rng(seed)
        obs, vinfo = venv.reset(seed=seed)
        sobs = []
        for i, e in enumerate(singles):
            o, info = e.reset(seed=seed + i)
            sobs.append(o)
            np.testing.assert_allclose(obs[i], o, rtol=0, atol=1e-9)
            _compare_info(info, vinfo, i, "reset")
        agents = [AnalyticAgent(e, stiffness=0.3) for e in singles] if policy == "analytic" else None
        needs_reset = np.zeros(N, dtype=bool)
        autoresets = 0
        for t in range(STEPS):
            if agents is None:
                acts = rng.uniform(-1, 1, venv.action_space.shape).astype(np.float32)
            else:
                acts = np.stack([a.predict(o, deterministic=True)[0] for a, o in zip(agents, sobs)])
            if t == DIVERGE[1]:
                venv.unwrapped.envs[DIVERGE[0]].data.qvel[:] = 1e12
                singles[DIVERGE[0]].unwrapped.data.qvel[:] = 1e12
            obs, rew, term, trunc, vinfo = venv.step(acts)
            for i, e in enumerate(singles):
                where = f"{env_id} seed {seed} step {t} world {i}"
                if needs_reset[i]:  # NEXT_STEP autoreset: this step only resets world i
                    o, info = e.reset()
                    r, te, tr = 0.0, False, False
                else:
                    o, r, te, tr, info = e.step(acts[i])
                sobs[i] = o
                np.testing.assert_allclose(obs[i], o, rtol=0, atol=1e-9, err_msg=where)
                np.testing.assert_allclose(rew[i], r, rtol=0, atol=1e-9, err_msg=where)
                assert (term[i], trunc[i]) == (te, tr), where
                _compare_info(info, vinfo, i, where)
            if t == DIVERGE[1]:
                assert term[DIVERGE[0]] and "simulation_error" in vinfo
            autoresets += int(needs_reset.sum())
            needs_reset = term | trunc
        assert autoresets >= 2 * N  # several episodes per world (and the diverged one)
        assert not venv.unwrapped.batch_sim.blocked.any()
        venv.close()


@pytest.mark.parametrize("task", record.TASKS)
def test_single_env_replays_the_recorded_reference(task):
    """The single env (a view of the same step code as the batch) against trajectories recorded from the code
    before the batched core existed (tests/reference/record.py), with the same library versions. MuJoCo's floats
    differ between CPUs: replayed on a second CPU (AMD EPYC family 25 model 1, AVX2 without AVX-512, 2026-12-02)
    the largest difference from the recording was 5.7e-13 relative (Insertion's contact force at 14,340 N in the
    diverged episode), the rest within 1e-9 absolute; the bound, 1e-9 relative or absolute, leaves a margin of
    about 1,700x over that spread."""
    ref = np.load(Path(__file__).parent / "reference" / "trajectories.npz")
    if not str(ref["machine"]).startswith(record.versions() + ","):
        pytest.skip(f"reference recorded with {ref['machine']}, this is {record.machine()}")
    for seed in record.SEEDS:
        for policy in ("random", "analytic"):
            env = gym.make(record.RECORDED_IDS[task], config=record.CONFIG)
            rec = record.run(env, lambda e: e.unwrapped.data, task, seed, policy)
            env.close()
            for k, v in rec.items():
                want = ref[f"{task}/{seed}/{policy}/{k}"]
                got = v.astype(np.float32) if k == "obs" else v
                np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9, err_msg=f"{task} {seed} {policy} {k}")


def test_make_vec_spaces_metadata_and_seeding():
    venv = make_batch("VSWrist/LoadHold-v0", n=4)
    single = gym.make("VSWrist/LoadHold-v0")
    assert venv.num_envs == 4
    assert venv.single_observation_space == single.observation_space
    assert venv.observation_space.shape == (4,) + single.observation_space.shape
    assert venv.action_space.shape == (4,) + single.action_space.shape
    assert venv.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
    o1, _ = venv.reset(seed=[10, 11, 12, 13])
    o2, _ = venv.reset(seed=10)
    np.testing.assert_array_equal(o1, o2)
    assert venv.observation_space.contains(o1)
    assert len({tuple(row) for row in o1}) == 4  # the worlds differ
    venv.close()


def test_dict_observations_and_other_action_modes_batch():
    venv = make_batch("VSWrist/Polish-v1", n=2, config={"obs_mode": "dict", "action_mode": "posture_compliance"})
    obs, _ = venv.reset(seed=0)
    assert set(obs) == set(venv.single_observation_space.spaces)
    obs, *_ = venv.step(venv.action_space.sample())
    assert venv.observation_space.contains(obs)
    assert venv.action_space.shape == (2, 6)
    venv.close()


@pytest.mark.parametrize("bad, match", [
    (lambda a: a.__setitem__((2, 1), np.nan), r"env 2: action holds NaN"),
    (lambda a: a.__setitem__((0, 3), np.inf), r"env 0: action holds inf"),
])
def test_bad_batched_actions_name_the_env_and_step_nothing(bad, match):
    venv = make_batch("VSWrist/Drill-v0")
    venv.reset(seed=1)
    before = [(e.sim.get_state(), e._step) for e in venv.envs]
    acts = np.zeros(venv.action_space.shape)
    bad(acts)
    with pytest.raises(ValueError, match=match):
        venv.step(acts)
    with pytest.raises(ValueError, match=r"shape \(3, 4\)"):
        venv.step(np.zeros((2, 4)))
    for e, (state, step) in zip(venv.envs, before):
        np.testing.assert_array_equal(e.sim.get_state(), state)
        assert e._step == step
    venv.close()


def test_same_step_autoreset_returns_the_final_observation():
    venv = make_batch("VSWrist/LoadHold-v0", n=2, config={"episode_s": 0.1},
                      autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)
    single = gym.make("VSWrist/LoadHold-v0", config={"episode_s": 0.1})
    venv.reset(seed=4)
    single.reset(seed=4)
    a = np.zeros(venv.action_space.shape)
    for _ in range(5):
        obs, r, term, trunc, info = venv.step(a)
        so, sr, _, st, _ = single.step(a[0])
    assert trunc.all() and st
    np.testing.assert_allclose(info["final_obs"][0], so, atol=1e-9)
    o, _ = single.reset()
    np.testing.assert_allclose(obs[0], o, atol=1e-9)
    venv.close()


def test_device_randomisation_rebuilds_each_worlds_model():
    cfg = {"randomize": {"spring_K": {"enabled": True, "range": [0.5, 1.5]}}}
    venv = make_batch("VSWrist/LoadHold-v0", config=cfg, threads=2)
    venv.reset(seed=3)
    Ks = [e.sim.params.spring.K for e in venv.envs]
    assert len(set(Ks)) == N  # one model per world
    for i, e in enumerate(venv.envs):
        single = gym.make("VSWrist/LoadHold-v0", config=cfg)
        single.reset(seed=3 + i)
        assert single.unwrapped.sim.params.spring.K == Ks[i]
    obs, r, *_ = venv.step(np.zeros(venv.action_space.shape))
    assert np.all(np.isfinite(r))
    venv.close()


def test_threads_default_to_the_cores_are_settable_and_serial_with_python_callbacks(monkeypatch):
    from vswrist_gym.envs.batch import default_threads
    from vswrist_gym.model import native

    venv = make_batch("VSWrist/LoadHold-v0", n=4)
    assert venv.threads == min(default_threads(), 4)
    venv.set_threads(1)
    assert venv.threads == 1
    with pytest.raises(ValueError, match="threads"):
        venv.set_threads(0)
    venv.close()
    monkeypatch.setenv("VSWRIST_THREADS", "3")  # what vswrist compare gives each of its concurrent trainings
    assert default_threads() == 3
    monkeypatch.setenv("VSWRIST_THREADS", "zero")
    with pytest.raises(ValueError, match="VSWRIST_THREADS"):
        default_threads()
    monkeypatch.delenv("VSWRIST_THREADS")
    # the fallback callbacks re-enter Python every substep: the batch steps serially whatever threads says
    monkeypatch.setenv("VSWRIST_NATIVE", "0")
    try:
        venv = make_batch("VSWrist/LoadHold-v0", n=4, threads=4)
        assert native.backend() == "python" and venv.backend == "python" and venv.threads == 1
        venv.reset(seed=0)
        _, r, *_ = venv.step(np.zeros(venv.action_space.shape))
        assert np.all(np.isfinite(r))
        venv.close()
    finally:
        monkeypatch.delenv("VSWRIST_NATIVE")
        native.install("c")


def test_pickled_batch_continues_identically():
    venv = make_batch("VSWrist/Impact-v0", n=2, threads=2)
    venv.reset(seed=0)
    a = np.full(venv.action_space.shape, 0.2)
    venv.step(a)
    twin = pickle.loads(pickle.dumps(venv))
    o1, r1, *_ = venv.step(a)
    o2, r2, *_ = twin.step(a)
    np.testing.assert_array_equal(o1, o2)
    np.testing.assert_array_equal(r1, r2)
    venv.close()
    twin.close()


def test_worlds_read_and_write_the_batch_episode_state():
    """The batch's episode state (``episode.EpisodeState``, (N,) arrays) and its worlds' own attributes are one
    memory: the batch's array step advances every world's clock, contact record and controller's command, a world's
    reset writes its row, and a pickled batch shares it again."""
    venv = make_batch("VSWrist/Impact-v0", n=3, threads=1)
    venv.reset(seed=0)
    a = np.full(venv.action_space.shape, 0.2)
    for _ in range(4):
        venv.step(a)
    ve = venv.unwrapped
    for twin in (ve, pickle.loads(pickle.dumps(ve))):
        ep = twin._ep
        np.testing.assert_array_equal(ep.step, [4, 4, 4])
        for i, e in enumerate(twin.envs):
            assert (e._step, e._t, e._peak_contact, e._sum_contact_sq) == (
                ep.step[i], ep.t[i], ep.peak_contact[i], ep.sum_contact_sq[i])
            assert type(e._step) is int and type(e._t) is float
            assert e.ctrl.lam == ep.lam[i] and np.shares_memory(e.ctrl._lam, ep.lam)
            np.testing.assert_array_equal(e.ctrl.posture_reference, ep.command[i])
            assert np.shares_memory(e.ctrl._ref, ep.command)
        twin.reset(options={"reset_mask": np.array([False, True, False])})
        assert ep.step[1] == 0 and ep.step[0] == 4 and ep.t[1] == 0.0
        twin.step(a)
        np.testing.assert_array_equal(ep.step, [5, 1, 5])
    venv.close()


def test_render_one_or_all_worlds(headless_gl):
    venv = make_batch("VSWrist/Polish-v1", n=2, render_mode="rgb_array", config={"render": {"width": 64,
                                                                                          "height": 48}})
    venv.reset(seed=0)
    frames = venv.render()
    assert len(frames) == 2 and frames[0].shape == (48, 64, 3)
    assert venv.render(env_index=1).shape == (48, 64, 3)
    venv.close()


def test_sb3_adapter_passes_sb3_checks_and_matches_the_batch():
    from stable_baselines3.common.vec_env import VecNormalize
    from stable_baselines3.common.vec_env.util import obs_space_info  # noqa: F401

    from vswrist_gym.agents.vec_env import BatchVecEnv

    sb3 = BatchVecEnv("VSWrist/LoadHold-v0", 2, {"episode_s": 0.1})
    sb3.seed(5)
    obs = sb3.reset()
    venv = make_batch("VSWrist/LoadHold-v0", n=2, config={"episode_s": 0.1})
    vobs, _ = venv.reset(seed=5)
    np.testing.assert_array_equal(obs, vobs)
    a = np.zeros((2, 4), dtype=np.float32)
    for t in range(5):
        obs, rew, done, infos = sb3.step(a)
        vobs, vrew, vterm, vtrunc, _ = venv.step(a)
        np.testing.assert_allclose(rew, vrew, atol=1e-5)
    assert done.all() and all(i["TimeLimit.truncated"] for i in infos)
    np.testing.assert_allclose(infos[0]["terminal_observation"], vobs[0])
    assert sb3.get_attr("task_id") == ["VSWrist/LoadHold-v0"] * 2
    assert sb3.env_method("success_description")[0]
    norm = VecNormalize(sb3)
    norm.reset()
    norm.step(a)
    norm.close()
    venv.close()


def test_sb3_trains_on_the_batch():
    from stable_baselines3 import PPO

    from vswrist_gym.agents.vec_env import BatchVecEnv

    sb3 = BatchVecEnv("VSWrist/LoadHold-v0", 4, {"episode_s": 0.2})
    model = PPO("MlpPolicy", sb3, n_steps=16, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(128)
    assert model.num_timesteps >= 128
    sb3.close()


@pytest.mark.parametrize("env_id", ["VSWrist/Polish-v0", "VSWrist/Drill-v0"])
def test_batched_evaluation_gives_the_serial_records(env_id):
    """The protocol's episodes of one seed as the worlds of a batch: the same records and trace as one env run
    episode after episode (the analytic agent acts row by row, so the equality is exact). Polish-v0: an older
    version, whose registered kwargs the batch must pass as gym.make does."""
    from vswrist_gym.agents.protocol import evaluate

    def make_agent(env):
        return AnalyticAgent(env, schedule=[(0.0, -0.5), (0.3, 0.5)])

    cfg = {"config": {"episode_s": 0.4}}
    serial, tr1 = evaluate(env_id, make_agent, [0, 1], 3, env_kwargs=cfg, trace_episode=(1, 2), batch=False)
    batched, tr2 = evaluate(env_id, make_agent, [0, 1], 3, env_kwargs=cfg, trace_episode=(1, 2))
    assert len(batched) == 6
    for a, b in zip(serial, batched):
        assert a.keys() == b.keys()
        for k in a:
            assert a[k] == b[k] or (a[k] != a[k] and b[k] != b[k]), (k, a[k], b[k])
    assert tr1 == tr2


def test_reset_mask_resets_only_the_masked_worlds():
    venv = make_batch("VSWrist/Impact-v0")
    obs0, _ = venv.reset(seed=20)
    a = np.zeros(venv.action_space.shape)
    obs1, *_ = venv.step(a)
    obs2, info = venv.reset(options={"reset_mask": np.array([False, True, False])})
    np.testing.assert_array_equal(obs2[[0, 2]], obs1[[0, 2]])  # untouched worlds keep their observation
    assert not np.array_equal(obs2[1], obs1[1]) and list(info["_posture_error"]) == [False, True, False]
    assert venv.envs[0]._step == 1 and venv.envs[1]._step == 0
    venv.close()


def _same_vector_info(a: dict, b: dict, where: str) -> None:
    assert set(a) == set(b), where
    for k, v in b.items():
        if k == "final_obs":
            for x, y in zip(a[k], v):
                assert (x is None) == (y is None), where
                if x is not None:
                    for name in (x if isinstance(x, dict) else [None]):
                        np.testing.assert_allclose(x[name] if name else x, y[name] if name else y, atol=1e-9)
        elif isinstance(v, dict):
            _same_vector_info(a[k], v, f"{where} {k}")
        elif v.dtype == object:
            assert list(a[k]) == list(v), f"{where} info {k}"
        else:
            np.testing.assert_allclose(a[k], v, rtol=0, atol=1e-9, err_msg=f"{where} info {k}")


@pytest.mark.parametrize("env_id, cfg", [
    ("VSWrist/Polish-v1", {"obs_mode": "dict", "action_mode": "residual", "gravity_compensation": True,
                           "randomize": {"spring_K": {"enabled": True, "range": [0.7, 1.3]}}}),
    ("VSWrist/Hammer-v0", {"action_mode": "motor", "stiffness_map": "linear"}),
    ("VSWrist/Insertion-v0", {"action_mode": "posture_compliance"}),
])
@pytest.mark.parametrize("threads", [1, 2])
def test_the_batch_equals_gymnasiums_vector_env_of_single_envs(env_id, cfg, threads):
    """The batch against Gymnasium's own ``SyncVectorEnv`` over single envs (world i seeded s + i there too), in
    the modes and settings the equivalence test above leaves out: dict observations, residual mode with gravity
    compensation, per-world spring models, motor and compliance modes, SAME_STEP autoresets (final observations
    and infos) and a divergence. On 2 threads the batch's worlds are finished chunk by chunk while other chunks
    step, and the worlds a chunk ended begin their resets early."""
    cfg = dict(cfg, episode_s=0.2)
    mode = gym.vector.AutoresetMode.SAME_STEP
    fast = make_batch(env_id, threads=threads, config=cfg, autoreset_mode=mode)
    slow = gym.vector.SyncVectorEnv([lambda: gym.make(env_id, config=cfg) for _ in range(N)], autoreset_mode=mode)
    out_f = _step_twins(fast, slow, seed=7, rng_seed=0, diverge=(2, 12))
    assert out_f[2][2] and out_f[4]["final_info"]["simulation_error"][2]


def _step_twins(a, b, seed: int, rng_seed: int, diverge: tuple[int, int], steps: int = 30):
    """Steps two batches with the same random actions from ``reset(seed)``, poisons world ``diverge[0]``'s
    velocities in both before step ``diverge[1]``, and checks every output equal (1e-9); returns ``a``'s output
    of the divergence step."""
    rng = np.random.default_rng(rng_seed)
    for venv in (a, b):
        venv.reset(seed=seed)
    at_divergence = None
    for t in range(steps):
        acts = rng.uniform(-1, 1, a.action_space.shape)
        if t == diverge[1]:
            for venv in (a, b):
                venv.unwrapped.envs[diverge[0]].unwrapped.data.qvel[:] = 1e12
        out_a, out_b = a.step(acts), b.step(acts)
        for x, y in zip(out_a[:4], out_b[:4]):
            if isinstance(x, dict):
                for k in x:
                    np.testing.assert_allclose(x[k], y[k], rtol=0, atol=1e-9, err_msg=f"step {t} obs {k}")
            else:
                np.testing.assert_allclose(x, y, rtol=0, atol=1e-9, err_msg=f"step {t}")
        _same_vector_info(out_a[4], out_b[4], f"step {t}")
        if t == diverge[1]:
            at_divergence = out_a
    for venv in (a, b):
        venv.close()
    return at_divergence


def test_sb3_adapter_infos_are_sb3s_own():
    """SB3's adapter reads one info dict per world (``step_worlds``), which the batch builds from its arrays:
    they must be the dicts SB3's own ``DummyVecEnv`` over single envs gives, terminal observations and time-limit
    flags included."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from vswrist_gym.agents.vec_env import BatchVecEnv

    cfg = {"episode_s": 0.1}
    fast = BatchVecEnv("VSWrist/Drill-v0", 3, env_kwargs={"config": cfg}, threads=1)
    slow = DummyVecEnv([lambda: gym.make("VSWrist/Drill-v0", config=cfg) for _ in range(3)])
    for v in (fast, slow):
        v.seed(3)
        v.reset()
    rng = np.random.default_rng(1)
    ends = 0
    for t in range(12):
        acts = rng.uniform(-1, 1, (3, 4))
        (of, rf, df, inf), (os_, rs, ds, ins) = fast.step(acts), slow.step(acts)
        np.testing.assert_allclose(of, os_, rtol=0, atol=1e-9)
        np.testing.assert_allclose(rf, rs, rtol=0, atol=1e-6)  # float32 rewards
        np.testing.assert_array_equal(df, ds)
        for a, b in zip(inf, ins):
            assert set(a) == set(b), t
            for k, v in b.items():
                if isinstance(v, str):
                    assert a[k] == v
                else:
                    np.testing.assert_allclose(a[k], v, rtol=0, atol=1e-9, err_msg=f"step {t} {k}")
            ends += "terminal_observation" in b
    assert ends >= 3
    fast.close()
    slow.close()


def test_a_task_overriding_a_step_method_is_refused(monkeypatch):
    """The batch computes the step methods over arrays, so it would not run a task's override of one: it refuses
    to make such a batch, naming the method, rather than step without it."""
    from vswrist_gym.envs.base import VSWristEnv
    from vswrist_gym.envs.load_hold import LoadHoldEnv

    def _info(self, weighted, final, err=None):
        return dict(VSWristEnv._info(self, weighted, final, err), extra_metric=1.5)

    monkeypatch.setattr(LoadHoldEnv, "_info", _info, raising=False)
    with pytest.raises(TypeError, match="LoadHoldEnv overrides _info: "):
        make_batch("VSWrist/LoadHold-v0", n=8)


def test_a_task_overriding_the_reward_is_run_by_the_batch_as_alone(monkeypatch):
    """The reward (``_step_reward``) is one method the single env and the batch both run: a task's override of it
    is not refused, and world 0 of a batch earns what the single env earns."""
    from vswrist_gym.envs.base import VSWristEnv
    from vswrist_gym.envs.load_hold import LoadHoldEnv

    def _step_reward(self, *args):
        weighted, reward = VSWristEnv._step_reward(self, *args)
        return weighted, reward + 0.25 * weighted["reward_energy"]

    monkeypatch.setattr(LoadHoldEnv, "_step_reward", _step_reward, raising=False)
    venv = make_batch("VSWrist/LoadHold-v0", n=2)
    env = gym.make("VSWrist/LoadHold-v0")
    venv.reset(seed=3)
    env.reset(seed=3)
    a = np.full(venv.action_space.shape, 0.3)
    for _ in range(3):
        _, rb, *_ = venv.step(a)
        _, r, _, _, info = env.step(a[0])
        assert rb[0] == r
        plain = sum(v for k, v in info.items() if k.startswith("reward_"))
        assert info["reward_energy"] != 0.0 and r == pytest.approx(plain + 0.25 * info["reward_energy"])
    venv.close()
    env.close()


@pytest.mark.parametrize("env_id", ["VSWrist/LoadHold-v0", "VSWrist/Polish-v1"])
@pytest.mark.parametrize("mode", [gym.vector.AutoresetMode.NEXT_STEP, gym.vector.AutoresetMode.SAME_STEP])
def test_threads_and_chunks_give_the_one_thread_numbers(env_id, mode):
    """8 worlds on 2 threads (2 chunks of 4: the caller finishes one chunk while the other steps, and resets
    settle on the pool) against the same batch on one thread, through autoresets and a divergence."""
    cfg = {"episode_s": 0.2}
    one, two = (make_batch(env_id, n=8, config=cfg, threads=t, autoreset_mode=mode) for t in (1, 2))
    assert two.unwrapped.threads == 2
    out = _step_twins(two, one, seed=11, rng_seed=3, diverge=(5, 7))
    assert out[2][5]  # the diverged world ended its episode


def test_many_chunks_on_two_threads_give_the_one_thread_numbers():
    """32 worlds on 2 threads: 8 chunks of 4. The first chunk begins and steps while the other 28 begin; the
    caller steps chunks, keeps the last for the pool thread, and finishes the rest in few calls of a few worlds
    each: against one thread, where every phase is one array call over the 32."""
    cfg = {"episode_s": 0.2}
    one, two = (make_batch("VSWrist/LoadHold-v0", n=32, config=cfg, threads=t) for t in (1, 2))
    assert "stiffness" in two.unwrapped.envs[0].obs_slices
    out = _step_twins(two, one, seed=5, rng_seed=8, diverge=(30, 4), steps=16)
    assert out[2][30]


def test_a_task_error_after_the_first_chunks_stepped_needs_a_reset(monkeypatch):
    """On threads the first chunk's physics starts before the other worlds' ``_begin``: should a task hook
    raise there, the batch refuses to step on from that half-stepped state until it is reset."""
    from gymnasium.error import ResetNeeded

    from vswrist_gym.envs.drill import DrillEnv

    venv = make_batch("VSWrist/Drill-v0", n=16, threads=2)
    venv.reset(seed=0)
    world = venv.unwrapped.envs[12]  # in a later chunk
    hook = DrillEnv._before_physics_worlds.__func__

    def broken(cls, worlds, ep, ids):  # Drill's load hook with a bug that shows in world 12's chunk only
        if world in worlds:
            raise RuntimeError("a bug in a task hook")
        hook(cls, worlds, ep, ids)

    monkeypatch.setattr(DrillEnv, "_before_physics_worlds", classmethod(broken))
    acts = np.zeros(venv.action_space.shape)
    with pytest.raises(RuntimeError, match="a bug in a task hook"):
        venv.step(acts)
    with pytest.raises(ResetNeeded):
        venv.step(acts)
    monkeypatch.undo()
    venv.reset(seed=0)  # draws the episode anew
    obs, rew, term, trunc, info = venv.step(acts)
    assert np.isfinite(obs).all() and np.isfinite(rew).all()
    venv.close()


def test_apply_wrenches_checks_the_rows_once():
    """The batch's wrench writer (Drill's and LoadHold's loads over arrays of worlds) refuses a non-finite or
    wrongly shaped array by name, and writes row k to world k."""
    venv = make_batch("VSWrist/LoadHold-v0", n=2)
    venv.reset(seed=0)
    sims = [e.sim for e in venv.unwrapped.envs]
    from vswrist_gym.sim import WristSim

    with pytest.raises(ValueError, match="wrenches must be finite"):
        WristSim.apply_wrenches(sims, np.full((2, 6), np.nan))
    with pytest.raises(ValueError, match="one .* row of 6"):
        WristSim.apply_wrenches(sims, np.zeros((3, 6)))
    W = np.arange(12.0).reshape(2, 6)
    WristSim.apply_wrenches(sims, W)
    for s, row in zip(sims, W):
        np.testing.assert_array_equal(s.data.xfrc_applied[s.hand_id], row)
    venv.close()


@pytest.mark.parametrize("env_id", IDS)
def test_reference_over_an_array_of_times_is_the_reference_at_each(env_id):
    """Tasks write ``_reference`` over arrays (a reset evaluates the episode's control instants in one call):
    each row at time t_k equals the reference asked for t_k alone, and a step's target is its row."""
    env = gym.make(env_id).unwrapped
    env.reset(seed=4)
    ts = np.arange(env.episode_steps + 1) * env.ctrl_dt
    table = env._reference(ts)
    assert table.shape == (len(ts), 3)
    for k in (0, 1, len(ts) // 3, len(ts) // 2, len(ts) - 1):
        np.testing.assert_array_equal(table[k], env._reference(float(ts[k])))
    for _ in range(3):
        env.step(env.action_space.sample())
    np.testing.assert_array_equal(env._target, table[3])
    env.close()
