"""One evaluation protocol for every agent (trained or analytic), per-episode metrics, and confidence intervals.

Episode `i` of evaluation seed `s` starts from `env.reset(seed=EVAL_SEED_BASE + 1000 s + i)`, so every agent
meets exactly the same initial conditions and task randomisation. Metrics are computed from the per-step `info`
of the environment (posture_error [rad], contact_force [N], peak_contact_force [N], elastic_energy [J],
lam [N m], is_success); a metric whose info key the environment does not provide is NaN.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

EVAL_SEED_BASE = 1_000_000  # far from training seeds (0, 1, ...) and their +rank offsets
EPISODES_PER_SEED_MAX = 1000

# metric name -> (unit, description); the order is the column order of tables and CSV files.
METRICS = {
    "return": ("", "sum of rewards"),
    "success": ("", "is_success at the last step (1/0)"),
    "rms_posture_error": ("rad", "RMS of info posture_error over the episode"),
    "peak_contact_force": ("N", "largest contact force of the episode"),
    "rms_contact_force": ("N", "RMS of info contact_force over the episode"),
    "elastic_energy": ("J", "mean elastic energy stored in the springs"),
    "stiffness_used": ("N m", "mean internal torque lambda (the stiffness the agent chose)"),
    "length": ("steps", "episode length"),
    # a task's own outcome, from the info of its last step; NaN on the tasks that do not report it
    "impact_speed": ("m/s", "Hammer: the head's speed normal to the anvil at the strike (0 if it missed)"),
}
TASK_METRICS = ("impact_speed",)  # read from the last step's info where the task reports them
# the range each metric's value can take: a confidence interval is cut to it (the true mean lies inside, so the
# cut interval covers it whenever the uncut one does); `success` is a rate, with its own interval (rate_ci)
METRIC_BOUNDS = {
    "return": (-math.inf, math.inf), "success": (0.0, 1.0), "rms_posture_error": (0.0, math.inf),
    "peak_contact_force": (0.0, math.inf), "rms_contact_force": (0.0, math.inf), "elastic_energy": (0.0, math.inf),
    "stiffness_used": (-math.inf, math.inf), "length": (0.0, math.inf), "impact_speed": (0.0, math.inf),
}
RATE_METRICS = ("success",)


EVAL_SEED_MAX = (2**32 - 1 - EVAL_SEED_BASE) // 1000 - 1  # keeps every reset seed a valid 32-bit NumPy seed

# The benchmark's seed ranges, fixed before any benchmark result. Training seeds seed the learner; evaluation
# seeds pick episodes (reset seeds `reset_seed(s, i)`). Hyperparameter search trains on TUNING_TRAIN_SEEDS and
# scores on TUNING_EVAL_SEEDS; task design, rule thresholds and schedule optimisation read only tuning
# episodes. HELDOUT_EVAL_SEEDS serve the final report alone: no tuning, selection or design step reads them.
BENCHMARK_TRAIN_SEEDS = tuple(range(0, 10))
TUNING_TRAIN_SEEDS = tuple(range(1000, 1010))
TUNING_EVAL_SEEDS = tuple(range(2048, 2058))
HELDOUT_EVAL_SEEDS = tuple(range(4096, 4106))


def reset_seed(seed: int, episode: int) -> int:
    if not 0 <= episode < EPISODES_PER_SEED_MAX:
        raise ValueError(f"episodes per seed must be in [1, {EPISODES_PER_SEED_MAX}]")
    return EVAL_SEED_BASE + 1000 * int(seed) + int(episode)


def check_eval_seeds(seeds, episodes: int) -> list[int]:
    """The evaluation seeds and episode count, checked before any environment is built."""
    if isinstance(episodes, bool) or not isinstance(episodes, (int, np.integer)) \
            or not 1 <= episodes <= EPISODES_PER_SEED_MAX:
        raise ValueError(f"episodes must be in [1, {EPISODES_PER_SEED_MAX}], got {episodes}")
    seeds = list(seeds)
    if not seeds:
        raise ValueError("at least one evaluation seed is needed")
    for s in seeds:
        if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or not 0 <= s <= EVAL_SEED_MAX:
            raise ValueError(f"evaluation seeds must be integers in [0, {EVAL_SEED_MAX}] (episode i of seed s "
                             f"resets with seed {EVAL_SEED_BASE} + 1000 s + i < 2**32), got {s}")
    return [int(s) for s in seeds]


@dataclass
class Trace:
    """Per-step signals of one episode, for plots."""

    time: list = field(default_factory=list)
    posture_error: list = field(default_factory=list)
    contact_force: list = field(default_factory=list)
    lam: list = field(default_factory=list)
    reward: list = field(default_factory=list)

    def to_dict(self) -> dict:
        return {k: [float(x) for x in v] for k, v in self.__dict__.items()}


def _info_value(info: dict, key: str) -> float:
    value = info.get(key)
    if value is None:
        return math.nan
    return float(np.asarray(value, dtype=float).reshape(-1)[0]) if np.size(value) == 1 else float(np.linalg.norm(value))


class _Episode:
    """The metric record and trace of one episode, built step by step (the same for a single env and a world of
    a batch)."""

    def __init__(self, dt: float):
        self.dt, self.trace = dt, Trace()
        self.total, self.steps, self.success, self.peak = 0.0, 0, math.nan, math.nan
        self.energies: list[float] = []
        self.task = {k: math.nan for k in TASK_METRICS}

    def add(self, reward: float, info: dict, done: bool) -> None:
        trace = self.trace
        self.steps += 1
        self.total += float(reward)
        trace.time.append(self.steps * self.dt)
        trace.posture_error.append(_info_value(info, "posture_error"))
        trace.contact_force.append(_info_value(info, "contact_force"))
        trace.lam.append(_info_value(info, "lam"))
        trace.reward.append(float(reward))
        self.energies.append(_info_value(info, "elastic_energy"))
        p = _info_value(info, "peak_contact_force")
        if not math.isnan(p):
            self.peak = p if math.isnan(self.peak) else max(self.peak, p)
        if done and "is_success" in info:
            self.success = float(bool(info["is_success"]))
        if done:
            self.task = {k: _info_value(info, k) for k in TASK_METRICS}

    def record(self) -> tuple[dict, Trace]:
        trace, peak = self.trace, self.peak
        force = np.asarray(trace.contact_force)
        if not np.all(np.isnan(force)):
            peak = float(np.nanmax(np.append(force, peak)))
        record = {
            "return": self.total,
            "success": self.success,
            "rms_posture_error": float(np.sqrt(np.mean(np.square(trace.posture_error)))),
            "peak_contact_force": peak,
            "rms_contact_force": float(np.sqrt(np.mean(np.square(force)))),
            "elastic_energy": float(np.mean(self.energies)),
            "stiffness_used": float(np.mean(trace.lam)),
            "length": float(self.steps),
            **self.task,
        }
        return record, trace


def run_episode(env, agent, seed: int, frames: list | None = None) -> tuple[dict, Trace]:
    """Run one episode deterministically; returns the metric record and the trace."""
    obs, info = env.reset(seed=seed)
    dt = float(getattr(env.unwrapped, "ctrl_dt", None) or getattr(env.unwrapped, "dt", 1.0))  # control period, s
    ep = _Episode(dt)
    state, episode_start = None, np.ones((1,), dtype=bool)
    if frames is not None:
        frames.append(env.render())
    while True:
        action, state = agent.predict(obs, state=state, episode_start=episode_start, deterministic=True)
        episode_start = np.zeros((1,), dtype=bool)
        obs, reward, terminated, truncated, info = env.step(action)
        if frames is not None:
            frames.append(env.render())
        ep.add(reward, info, terminated or truncated)
        if terminated or truncated:
            break
    return ep.record()


def run_episodes_batched(venv, agent, first_seed: int) -> list[tuple[dict, Trace]]:
    """One episode in every world of a VS-Wrist batch (``gym.make_vec``), world i from seed ``first_seed + i``:
    the same records as ``run_episode`` on ``gym.make`` with those seeds, the policy queried once per step for
    all worlds. A world that has ended is reset by the batch and its further steps are ignored."""
    n = venv.num_envs
    obs, _ = venv.reset(seed=first_seed)
    eps = [_Episode(float(venv.unwrapped.envs[0].ctrl_dt)) for _ in range(n)]
    active = np.ones(n, dtype=bool)
    state, episode_start = None, np.ones(n, dtype=bool)
    while active.any():
        action, state = agent.predict(obs, state=state, episode_start=episode_start, deterministic=True)
        episode_start = np.zeros(n, dtype=bool)
        obs, reward, terminated, truncated, info = venv.step(action)
        done = terminated | truncated
        for i in np.flatnonzero(active):
            world = {k: v[i] for k, v in info.items() if not k.startswith("_") and info.get(f"_{k}", active)[i]}
            eps[i].add(reward[i], world, bool(done[i]))
            if done[i]:
                active[i] = False
    return [ep.record() for ep in eps]


BATCH_EPISODES = True  # evaluate's default: the episodes of a seed as the worlds of one batch


def _batchable(env_id: str) -> bool:
    import gymnasium as gym

    spec = gym.registry.get(env_id)
    return spec is not None and env_id.startswith("VSWrist/") and spec.vector_entry_point is not None


def evaluate(env_id: str, make_agent, seeds, episodes: int, env_kwargs: dict | None = None,
             trace_episode: tuple[int, int] | None = None, video_path: str | Path | None = None,
             progress=None, on_record=None, batch: bool | None = None,
             desc: str | None = None) -> tuple[list[dict], dict | None]:
    """Evaluate one agent under the protocol; returns per-episode records and the requested episode's trace.

    With ``batch`` (default ``BATCH_EPISODES``) the episodes of one seed run as the worlds of one VS-Wrist batch
    (``gym.make_vec``), the same episodes as one ``gym.make`` env run episode after episode; their records
    then arrive (and are saved) seed by seed.

    `make_agent(env)` builds the agent for an environment (the analytic agent needs it; a trained one ignores it).
    `on_record(records)` is called with the records so far after every episode (to save them as they come).
    `desc` names the agent on the progress bar (agents.progress: drawn on a terminal only).
    """
    import gymnasium as gym

    import vswrist_gym  # noqa: F401
    from vswrist_gym.agents.progress import bar

    seeds = check_eval_seeds(seeds, episodes)
    env_kwargs = dict(env_kwargs or {})
    env = gym.make(env_id, **env_kwargs)
    venv = None
    shown = bar(total=len(seeds) * episodes, desc=f"{desc or env_id}: episodes", unit="episode")
    try:
        agent = make_agent(env)
        records, trace = [], None
        if (BATCH_EPISODES if batch is None else batch) and episodes > 1 and _batchable(env_id):
            venv = gym.make_vec(env_id, num_envs=episodes, vectorization_mode="vector_entry_point", **env_kwargs)
        for s in seeds:
            # reset_seed(s, i) = reset_seed(s, 0) + i: world i of a batch seeded reset_seed(s, 0) is episode i
            runs = run_episodes_batched(venv, agent, reset_seed(s, 0)) if venv is not None else \
                (run_episode(env, agent, reset_seed(s, i)) for i in range(episodes))
            for i, (rec, tr) in enumerate(runs):
                records.append({"seed": s, "episode": i, "reset_seed": reset_seed(s, i), **rec})
                if trace_episode == (s, i):
                    trace = tr.to_dict()
                if on_record is not None:
                    on_record(records)
                if progress is not None:
                    progress()
                shown.update()
    finally:
        shown.close()
        env.close()
        if venv is not None:
            venv.close()
    if video_path is not None:
        write_video(env_id, make_agent, env_kwargs, reset_seed(seeds[0], 0), Path(video_path))
    return records, trace


def write_video(env_id: str, make_agent, env_kwargs: dict, seed: int, path: Path) -> None:
    """Render one episode with the environment's rgb_array mode and write it (mp4/gif by suffix)."""
    import gymnasium as gym
    import imageio

    env = gym.make(env_id, render_mode="rgb_array", **env_kwargs)
    try:
        frames: list = []
        run_episode(env, make_agent(env), seed, frames=frames)
        fps = env.metadata.get("render_fps") or 30
    finally:
        env.close()
    path.parent.mkdir(parents=True, exist_ok=True)
    imageio.mimsave(path, [np.asarray(f) for f in frames if f is not None], fps=fps)


# ------------------------------------------------------------------------------------------------ statistics


def t_quantile(p: float, df: int) -> float:
    """Quantile of Student's t distribution (scipy.stats.t), checked for the range the intervals use."""
    if df < 1:
        raise ValueError("df must be at least 1")
    if not 0.5 <= p < 1:
        raise ValueError("p must be in [0.5, 1)")
    from scipy.stats import t

    return float(t.ppf(p, df))


def mean_ci(values, level: float = 0.95, bounds: tuple[float, float] = (-math.inf, math.inf)) -> dict:
    """Mean and the Student-t confidence interval of the mean (scipy.stats.t), cut to `bounds`, the range the
    values can take; the interval is NaN for fewer than two values."""
    x = np.asarray([v for v in values if not math.isnan(v)], dtype=float)
    n = len(x)
    if n == 0:
        return {"mean": math.nan, "low": math.nan, "high": math.nan, "n": 0}
    mean = float(x.mean())
    if n < 2:
        return {"mean": mean, "low": math.nan, "high": math.nan, "n": 1}
    half = t_quantile(0.5 + level / 2, n - 1) * float(x.std(ddof=1)) / math.sqrt(n)
    return {"mean": mean, "low": max(mean - half, bounds[0]), "high": min(mean + half, bounds[1]), "n": n}


def rate_ci(outcomes, level: float = 0.95) -> dict:
    """Rate of 0/1 outcomes with the Wilson score interval (scipy.stats.binomtest), which stays in [0, 1] and
    has an interval for a single outcome too; NaN outcomes (not reported) are left out."""
    from scipy.stats import binomtest

    x = [float(v) for v in outcomes if not math.isnan(v)]
    n = len(x)
    if n == 0:
        return {"mean": math.nan, "low": math.nan, "high": math.nan, "n": 0}
    k = int(round(sum(x)))
    ci = binomtest(k, n).proportion_ci(confidence_level=level, method="wilson")
    return {"mean": k / n, "low": float(ci.low), "high": float(ci.high), "n": n}


def summarise(records: list[dict]) -> dict:
    """Per metric: mean over the episodes of each seed, then mean and 95 % CI over seeds (Student-t, cut to the
    metric's range); a rate (success) gets the Wilson interval over all its episodes instead."""
    seeds = sorted({r["seed"] for r in records})
    out = {}
    for name in METRICS:
        # records written before a metric existed lack it: NaN, as for a task that does not report it
        per_seed = [float(np.nanmean([r.get(name, math.nan) for r in records if r["seed"] == s]))
                    if not all(math.isnan(r.get(name, math.nan)) for r in records if r["seed"] == s) else math.nan
                    for s in seeds]
        if name in RATE_METRICS:
            ci = rate_ci([_nan(r.get(name)) for r in records])
            ci["mean"] = float(np.nanmean(per_seed)) if not all(math.isnan(v) for v in per_seed) else math.nan
        else:
            ci = mean_ci(per_seed, bounds=METRIC_BOUNDS.get(name, (-math.inf, math.inf)))
        out[name] = {**ci, "per_seed": per_seed, "seeds": seeds, "unit": METRICS[name][0]}
    return out


def _nan(value) -> float:
    return math.nan if value is None else float(value)


def json_safe(obj):
    """JSON cannot hold NaN: write null instead."""
    if isinstance(obj, float):
        return None if math.isnan(obj) or math.isinf(obj) else obj
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


PARTIAL_FILE = "episodes.partial.jsonl"  # the episodes finished so far; gone once metrics.json is written


def write_partial(out_dir: Path, header: dict, records: list[dict]) -> Path:
    """Rewrite DIR/episodes.partial.jsonl (a header line, then one line per finished episode) atomically, so a
    crash or kill during an evaluation loses no finished episode and never leaves a half-written file."""
    from vswrist_gym.agents.fileio import atomic_write_text

    path = Path(out_dir) / PARTIAL_FILE
    lines = [json.dumps(json_safe({"header": header}))] + [json.dumps(json_safe(r)) for r in records]
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


def read_partial(path: Path) -> tuple[dict, list[dict]]:
    """Header and episode records of an episodes.partial.jsonl (None stands for NaN)."""
    lines = Path(path).read_text().splitlines()
    return json.loads(lines[0])["header"], [json.loads(line) for line in lines[1:]]


def write_metrics(out_dir: Path, header: dict, records: list[dict], summary: dict) -> tuple[Path, Path]:
    """DIR/metrics.json and DIR/metrics.csv, each written atomically; then the partial file is dropped."""
    from vswrist_gym.agents.fileio import atomic_write_text

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path, csv_path = out_dir / "metrics.json", out_dir / "metrics.csv"
    doc = {**header, "metrics": {k: {"unit": u, "description": d} for k, (u, d) in METRICS.items()},
           "summary": summary, "episodes": records}
    atomic_write_text(json_path, json.dumps(json_safe(doc), indent=2))
    buf = io.StringIO(newline="")
    writer = csv.DictWriter(buf, fieldnames=["agent", "seed", "episode", "reset_seed", *METRICS])
    writer.writeheader()
    for r in records:
        writer.writerow({"agent": header.get("agent", ""), **{k: r[k] for k in writer.fieldnames if k in r}})
    atomic_write_text(csv_path, buf.getvalue())
    (out_dir / PARTIAL_FILE).unlink(missing_ok=True)
    return json_path, csv_path
