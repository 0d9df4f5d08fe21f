"""The validity gate: does a task need a variable stiffness? Headroom and necessity under the benchmark protocol.

``vswrist gate [--tasks ...] [--stage headroom|necessity|feedback|all] [--write docs/environments.md]`` measures, per task:

* **Selection, on tuning episodes only** (``TUNING_EVAL_SEEDS`` x ``EPISODES_PER_SEED``, ``protocol.reset_seed``):
  the best constant stiffness command among ``probe.CONSTANT_COMMANDS`` (the reference agent at that command), and
  the soft and stiff levels (``RULE_LEVELS``) of the task's observation-only rule (``probe.adaptive_policy``
  mapped onto them by ``probe.within``), each by the highest mean return. ``select`` refuses any other seed.
* **Headroom, on held-out episodes** (``HELDOUT_EVAL_SEEDS`` x ``EPISODES_PER_SEED`` = 100): the selected rule
  minus the selected constant, episode by episode; its mean and the standard error of that mean. It passes when
  the mean is at least ``HEADROOM_SE`` standard errors above zero.
* **Necessity, on the same held-out episodes**: a posture-only PPO (the packaged entry of ``configs/ppo.yaml`` in
  the ``residual`` action mode with ``stiffness_scale`` 0, the stiffness held at the selected constant, the posture
  residual ``POSTURE_SCALE`` rad) trained for ``BUDGET`` steps on each of ``NECESSITY_SEEDS``; per training seed,
  its mean paired gain over the constant as a share of the headroom; the Student-t 95 % interval of that share
  over the training seeds. It passes when the interval's upper end is below ``NECESSITY_SHARE``: a posture trim
  cannot stand in for the stiffness.

* **Posture feedback, the same held-out episodes**: a hand-written posture-only agent at the selected constant
  (``IntegralTrim``: an integral trim of the posture reference on the measured RUD/FE error, switched on with the
  task's cue where it has one), its rate chosen among ``FEEDBACK_GAINS`` on the tuning episodes; its paired gain
  over the constant as a share of the headroom, with a normal 95 % interval from the paired standard error. It
  passes when the interval's upper end is below ``NECESSITY_SHARE``: a learner that fails to find a posture
  substitute is not taken as proof that none exists.

A task passes the gate when all three pass. Each task's results go to ``OUT/<Task>-vN.json`` as they come (selection,
headroom, every training seed), so a stopped run resumes where it stopped; the trained runs go to
``RUNS_DIR/<Task>-vN/seed<k>`` (a half-trained run resumes from its checkpoint). ``--write`` rebuilds the
``gate`` block of docs/environments.md from the JSON files, computing nothing that is missing.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import platform
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from vswrist_gym.agents.protocol import (BENCHMARK_TRAIN_SEEDS, HELDOUT_EVAL_SEEDS, TUNING_EVAL_SEEDS, mean_ci,
                                         reset_seed)
from vswrist_gym.tools.probe import CONSTANT_COMMANDS

EPISODES_PER_SEED = 10        # episodes per evaluation seed: 10 seeds x 10 = 100 episodes for selection and report
RULE_LEVELS = tuple((lo, hi) for lo in CONSTANT_COMMANDS for hi in CONSTANT_COMMANDS if lo < hi)  # (soft, stiff)
HEADROOM_SE = 5.0             # headroom passes at a paired mean >= this many paired standard errors
NECESSITY_SHARE = 0.5         # necessity passes when the share's 95 % upper bound is below this
NECESSITY_SEEDS = BENCHMARK_TRAIN_SEEDS[:3]   # training seeds of the posture-only PPO
BUDGET = 80_000               # env steps per posture-only PPO run: the packaged entries' n_timesteps
POSTURE_SCALE = 0.15          # rad: the posture residual of the packaged full-track entries (configs/ppo.yaml)
LEVEL = 0.95                  # confidence level of the share's interval
FEEDBACK_GAINS = (0.0, 2.0, 5.0, 10.0, 20.0)   # 1/s: the posture feedback's trim rate per rad of error


class GateError(ValueError):
    """Bad input or a stored result that does not match the protocol; the message names the field."""


# ------------------------------------------------------------------------------------------------ statistics


def paired(a, b) -> dict:
    """Episode-by-episode difference a - b: its mean, the standard error of the mean (sample s.d. / sqrt(n)),
    n, and the share of episodes where a is higher."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or a.ndim != 1 or len(a) < 2:
        raise GateError(f"paired returns need two equal-length lists of at least 2 episodes, got {a.shape} and "
                        f"{b.shape}")
    d = a - b
    return {"mean": float(d.mean()), "se": float(d.std(ddof=1) / math.sqrt(len(d))), "n": int(len(d)),
            "wins": float(np.mean(d > 0.0))}


def headroom_passes(diff: dict, k: float = HEADROOM_SE) -> bool:
    """A paired mean at least k standard errors above zero (a zero standard error needs a positive mean)."""
    return diff["mean"] > 0.0 and diff["mean"] >= k * diff["se"]


def share_interval(gains, headroom: float, level: float = LEVEL) -> dict:
    """Each training seed's paired gain over the constant as a share of the headroom, and the Student-t interval of
    the mean share over the seeds (``protocol.mean_ci``); NaN where the headroom is not positive (no share)."""
    if not headroom > 0.0:
        return {"shares": [math.nan] * len(gains), "mean": math.nan, "low": math.nan, "high": math.nan,
                "n": len(gains)}
    shares = [float(g) / headroom for g in gains]
    return {"shares": shares, **mean_ci(shares, level=level)}


def necessity_passes(share: dict, limit: float = NECESSITY_SHARE) -> bool:
    """The share's upper bound below ``limit`` (an interval needs two training seeds at least)."""
    return share["n"] >= 2 and not math.isnan(share["high"]) and share["high"] < limit


# ------------------------------------------------------------------------------------------------ episodes


def _check_seeds(seeds, allowed: tuple, use: str, name: str) -> list[int]:
    seeds = list(seeds)
    bad = [s for s in seeds if s not in allowed]
    if not seeds or bad:
        raise GateError(f"{use} seeds must be {'held-out' if name.startswith('HELDOUT') else 'tuning'} evaluation seeds ({allowed[0]}-"
                        f"{allowed[-1]}, protocol.{name}), got {bad or 'none'}")
    return seeds


def check_tuning_seeds(seeds) -> list[int]:
    """Selection reads tuning evaluation seeds only: any other seed (the held-out ones above all) is refused."""
    return _check_seeds(seeds, TUNING_EVAL_SEEDS, "selection", "TUNING_EVAL_SEEDS")


def check_heldout_seeds(seeds) -> list[int]:
    """The report reads held-out evaluation seeds only."""
    return _check_seeds(seeds, HELDOUT_EVAL_SEEDS, "report", "HELDOUT_EVAL_SEEDS")


class _PolicyAgent:
    """A stateful function obs -> action (the probe's rules) behind SB3's ``predict``, rebuilt at every episode
    start so that no state leaks from one episode into the next."""

    def __init__(self, build):
        self.build, self.policy = build, None

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        if self.policy is None or (episode_start is not None and bool(np.asarray(episode_start).reshape(-1)[0])):
            self.policy = self.build()
        return np.asarray(self.policy(obs), dtype=np.float32), None


def constant_agent(c: float):
    from vswrist_gym.tools.probe import constant_policy

    return lambda env: _PolicyAgent(lambda: constant_policy(env, c))


CUE_TERMS = ("load_cue", "engage_cue")   # LoadHold-v1, Drill-v1: a load or drill announced ahead of its onset


def cue_policy(env):
    """The rule of a task whose observation announces its load (``CUE_TERMS``): stiff while the cue is on, soft
    otherwise, the command moved at the probe's slew limit. Where there is no cue, the probe's rule."""
    from vswrist_gym.tools.probe import _slew, adaptive_policy

    u = env.unwrapped
    sl = u.obs_slices
    names = [n for n in CUE_TERMS if n in sl]
    if not names:
        return adaptive_policy(env)
    cue, target, state = sl[names[0]], sl["target"], {}

    def act(obs):
        obs = np.asarray(obs, dtype=float)
        s = 1.0 if obs[cue][0] > 0.5 else -1.0
        return u.reference_to_action(obs[target], _slew(state, s, u.ctrl_dt))
    return act


class IntegralTrim:
    """A posture-only agent in the gate's residual mode (stiffness held at the constant, posture residual
    ``POSTURE_SCALE`` rad): trim <- trim - k ctrl_dt (posture - target) on RUD and FE, clipped to the residual's
    range, on from the task's cue (``CUE_TERMS``) or from the start where there is none. What a posture feedback
    can do without learning: the simplest substitute for a stiffness against a slow or static load."""

    def __init__(self, env, k: float):
        u = env.unwrapped
        self.k, self.dt, self.sl = float(k), u.ctrl_dt, u.obs_slices
        self.cue = next((self.sl[n] for n in CUE_TERMS if n in self.sl), None)
        self.trim = np.zeros(2)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(obs, dtype=float)
        if episode_start is not None and bool(np.asarray(episode_start).reshape(-1)[0]):
            self.trim = np.zeros(2)
        if self.cue is None or obs[self.cue][0] > 0.5:
            err = obs[self.sl["posture"]][:2] - obs[self.sl["target"]][:2]
            self.trim = np.clip(self.trim - self.k * self.dt * err, -POSTURE_SCALE, POSTURE_SCALE)
        return np.array([self.trim[0] / POSTURE_SCALE, self.trim[1] / POSTURE_SCALE, 0.0, 0.0],
                        dtype=np.float32), None


def feedback_kwargs(best_constant: float) -> dict:
    """The residual mode of the posture feedback: the stiffness held at the constant, the posture residual."""
    return {"config": {"action_mode": "residual", "residual": {
        "posture_scale": POSTURE_SCALE, "stiffness_scale": 0.0, "stiffness_nominal": float(best_constant)}}}


def feedback(env_id: str, selection: dict, constant_heldout, headroom_mean: float, gains=FEEDBACK_GAINS,
             tuning=TUNING_EVAL_SEEDS, heldout=HELDOUT_EVAL_SEEDS, episodes: int = EPISODES_PER_SEED,
             runner=None) -> dict:
    """The posture feedback's rate chosen on tuning episodes (paired against the constant there), then its gain
    over the constant on the held-out episodes (``constant_heldout``: the constant's returns there, in order) and
    its share of the headroom with a normal interval from the paired standard error."""
    tuning, heldout = check_tuning_seeds(tuning), check_heldout_seeds(heldout)
    runner = runner or episode_returns
    c = selection["best_constant"]
    kw = feedback_kwargs(c)
    const_t = runner(env_id, constant_agent(c), tuning, episodes, {"config": {}})
    on_tuning = {g: paired(runner(env_id, lambda env, g=g: IntegralTrim(env, g), tuning, episodes, kw),
                           const_t)["mean"] for g in gains}
    k = max(on_tuning, key=on_tuning.get)   # first of equals, in gains order
    returns = runner(env_id, lambda env: IntegralTrim(env, k), heldout, episodes, kw)
    return {"gains": list(gains), "tuning_gain": {f"{g:g}": m for g, m in on_tuning.items()}, "k": float(k),
            "returns": returns, **feedback_verdict(paired(returns, constant_heldout), headroom_mean)}


def feedback_verdict(gain: dict, headroom_mean: float, level: float = LEVEL) -> dict:
    """The posture feedback's paired gain (``paired``) as a share of the headroom, with the normal interval of the
    gain's mean divided by the headroom; it passes when the upper end is below ``NECESSITY_SHARE``."""
    from scipy.stats import norm

    z = float(norm.ppf(0.5 + level / 2))
    if headroom_mean > 0.0:
        share = {"mean": gain["mean"] / headroom_mean, "low": (gain["mean"] - z * gain["se"]) / headroom_mean,
                 "high": (gain["mean"] + z * gain["se"]) / headroom_mean}
    else:
        share = {"mean": math.nan, "low": math.nan, "high": math.nan}
    return {"gain": gain, "share": share,
            "passes": bool(not math.isnan(share["high"]) and share["high"] < NECESSITY_SHARE)}


def passes(doc: dict) -> bool:
    """Whether a task's gate result passes: headroom, the posture-only learner's necessity and the posture
    feedback's."""
    nec = (doc.get("necessity") or {}).get("summary") or {}
    return bool(doc.get("headroom", {}).get("passes") and nec.get("passes") and
                (doc.get("feedback") or {}).get("passes"))


def rule_agent(levels: tuple[float, float]):
    from vswrist_gym.tools.probe import within

    return lambda env: _PolicyAgent(lambda: within(cue_policy(env), tuple(levels)))


def episode_returns(env_id: str, make_agent, seeds, episodes: int, env_kwargs: dict | None = None) -> list[float]:
    """Returns of the protocol's episodes (``protocol.evaluate``, one environment, episode after episode: the rules
    read one environment's state), in the order seed by seed, episode by episode."""
    from vswrist_gym.agents.protocol import evaluate

    records, _ = evaluate(env_id, make_agent, seeds, episodes, env_kwargs=env_kwargs, batch=False)
    return [float(r["return"]) for r in records]


def select(env_id: str, seeds=TUNING_EVAL_SEEDS, episodes: int = EPISODES_PER_SEED, config: dict | None = None,
           runner=episode_returns) -> dict:
    """The best constant command and the rule's best (soft, stiff) levels, by mean return on tuning episodes only
    (any other seed is refused before an episode runs)."""
    seeds = check_tuning_seeds(seeds)
    kwargs = {"config": dict(config or {})}
    constants = {c: float(np.mean(runner(env_id, constant_agent(c), seeds, episodes, kwargs)))
                 for c in CONSTANT_COMMANDS}
    rules = {lv: float(np.mean(runner(env_id, rule_agent(lv), seeds, episodes, kwargs))) for lv in RULE_LEVELS}
    best = max(constants, key=constants.get)   # first of equals, in CONSTANT_COMMANDS order
    levels = max(rules, key=rules.get)
    return {"seeds": seeds, "episodes_per_seed": episodes,
            "constants": {f"{c:+.1f}": m for c, m in constants.items()},
            "rules": {f"{lo:+.1f},{hi:+.1f}": m for (lo, hi), m in rules.items()},
            "best_constant": float(best), "rule_levels": [float(levels[0]), float(levels[1])]}


def headroom(env_id: str, selection: dict, seeds=HELDOUT_EVAL_SEEDS, episodes: int = EPISODES_PER_SEED,
             config: dict | None = None, runner=episode_returns) -> dict:
    """The selected rule against the selected constant on held-out episodes, paired; every other constant too,
    for the record (nothing is chosen from them)."""
    seeds = check_heldout_seeds(seeds)
    kwargs = {"config": dict(config or {})}
    constants = {f"{c:+.1f}": runner(env_id, constant_agent(c), seeds, episodes, kwargs) for c in CONSTANT_COMMANDS}
    rule = runner(env_id, rule_agent(tuple(selection["rule_levels"])), seeds, episodes, kwargs)
    best = constants[f"{selection['best_constant']:+.1f}"]
    diff = paired(rule, best)
    return {"seeds": seeds, "episodes_per_seed": episodes,
            "reset_seeds": [reset_seed(s, i) for s in seeds for i in range(episodes)],
            "returns": {"constant": constants, "rule": rule}, "rule_minus_constant": diff,
            "z": diff["mean"] / diff["se"] if diff["se"] > 0 else math.inf,
            "passes": headroom_passes(diff)}


# ------------------------------------------------------------------------------------------------ necessity


def posture_only_entry(env_id: str, best_constant: float, budget: int = BUDGET) -> dict:
    """The packaged PPO entry of ``env_id`` (its own or, for a version without one, its task's newest entry) in the
    residual mode with the stiffness fixed at ``best_constant`` and a ``POSTURE_SCALE`` posture residual, as a
    hyperparameter file's content (the entry and its ``vswrist:`` run settings)."""
    entry, settings = packaged_entry(env_id, "ppo")
    entry["n_timesteps"] = int(budget)
    entry["env_kwargs"] = {**entry.get("env_kwargs", {}), "action_mode": "residual",
                           "residual": {"posture_scale": POSTURE_SCALE, "stiffness_scale": 0.0,
                                        "stiffness_nominal": float(best_constant)}}
    return {env_id: entry, "vswrist": {env_id: settings}}


def packaged_entry(env_id: str, algo: str) -> tuple[dict, dict]:
    """A copy of the packaged ``configs/<algo>.yaml`` entry of ``env_id`` (or, for a version without one, of its
    task's newest version that has one) and its ``vswrist:`` run settings."""
    import copy

    from vswrist_gym.agents.hparams import default_config_path, read_file

    data, section = read_file(default_config_path(algo))
    source = env_id if env_id in data else None
    if source is None:
        short = env_id.split("/")[-1].rsplit("-v", 1)[0]
        found = sorted(k for k in data if k.split("/")[-1].rsplit("-v", 1)[0] == short)
        if not found:
            raise GateError(f"configs/{algo}.yaml has no entry for {env_id} or another version of it")
        source = found[-1]
    return copy.deepcopy(data[source]), dict(section.get(source, {}))


def train_posture_only(env_id: str, best_constant: float, seed: int, runs_dir: Path, budget: int = BUDGET,
                       log=print) -> Path:
    """Train (or finish) one posture-only PPO run; returns its run directory."""
    import yaml

    from vswrist_gym.agents.train import train

    run_dir = Path(runs_dir) / env_id.split("/")[-1] / f"seed{seed}"
    if (run_dir / "model.zip").is_file():
        return run_dir
    cfg_path = Path(runs_dir) / env_id.split("/")[-1] / "posture_only_ppo.yaml"
    cfg_path.parent.mkdir(parents=True, exist_ok=True)
    cfg_path.write_text(yaml.safe_dump(posture_only_entry(env_id, best_constant, budget), sort_keys=False))
    resume = (run_dir / "config.yaml").is_file()
    train(env_id, "ppo", run_dir, config=None if resume else cfg_path, timesteps=budget, seed=seed, resume=resume,
          progress=False, log=log)
    return run_dir


def trained_returns(run_dir: Path, env_id: str, seeds=HELDOUT_EVAL_SEEDS,
                    episodes: int = EPISODES_PER_SEED) -> list[float]:
    from vswrist_gym.agents.evaluate import AgentSpec

    spec = AgentSpec(str(run_dir), checkpoint="final")
    spec.check_task(env_id)
    return episode_returns(env_id, spec.make, check_heldout_seeds(seeds), episodes, spec.env_kwargs)


def shipped_against_constant(task: str, track: str, gate_dir: Path, episodes_per_seed: int = EPISODES_PER_SEED,
                             seeds=HELDOUT_EVAL_SEEDS) -> dict:
    """A shipped policy against the best constant its id's gate selected on tuning episodes, paired on held-out
    episodes: the difference's mean, s.e., 95 % Student-t interval and whether it loses beyond that interval."""
    from vswrist_gym.agents.evaluate import AgentSpec
    from vswrist_gym.agents.protocol import mean_ci

    spec = AgentSpec(f"pretrained:{task}:{track}")
    env_id = spec.trained.env_id
    path = result_path(gate_dir, env_id)
    if not path.is_file():
        raise GateError(f"no gate result for {env_id} in {gate_dir} (run `vswrist gate --tasks {env_id} "
                        f"--stage headroom` first)")
    best = json.loads(path.read_text())["selection"]["best_constant"]
    seeds = check_heldout_seeds(seeds)
    policy = episode_returns(env_id, spec.make, seeds, episodes_per_seed, spec.env_kwargs)
    constant = episode_returns(env_id, constant_agent(best), seeds, episodes_per_seed, {})
    diff = paired(policy, constant)
    ci = mean_ci(np.asarray(policy) - np.asarray(constant))
    return {"task": task, "track": track, "env_id": env_id, "best_constant": best, "difference": diff,
            "ci": [ci["low"], ci["high"]], "loses": bool(ci["high"] < 0.0)}


def necessity_summary(doc: dict) -> dict:
    """Per training seed the posture-only PPO's paired gain over the constant; the share of the headroom and its
    interval over the seeds; the verdict."""
    hr = doc["headroom"]
    const = hr["returns"]["constant"][f"{doc['selection']['best_constant']:+.1f}"]
    runs = doc["necessity"]["runs"]
    seeds = [s for s in doc["necessity"]["seeds"] if str(s) in runs]
    gains = {s: paired(runs[str(s)]["returns"], const) for s in seeds}
    share = share_interval([gains[s]["mean"] for s in seeds], hr["rule_minus_constant"]["mean"])
    complete = len(seeds) == len(doc["necessity"]["seeds"])
    return {"gains": {str(s): g for s, g in gains.items()}, "share": share, "complete": complete,
            "passes": complete and necessity_passes(share)}


# ------------------------------------------------------------------------------------------------ one task


def protocol_block(budget: int = BUDGET, train_seeds=NECESSITY_SEEDS) -> dict:
    return {"tuning_eval_seeds": list(TUNING_EVAL_SEEDS), "heldout_eval_seeds": list(HELDOUT_EVAL_SEEDS),
            "episodes_per_seed": EPISODES_PER_SEED, "constants": list(CONSTANT_COMMANDS),
            "rule_levels": [list(lv) for lv in RULE_LEVELS], "headroom_se": HEADROOM_SE,
            "necessity_share": NECESSITY_SHARE, "necessity_seeds": [int(s) for s in train_seeds],
            "budget": int(budget), "posture_scale": POSTURE_SCALE, "level": LEVEL}


def _stamp(doc: dict, stage: str) -> None:
    doc.setdefault("made", {})[stage] = {
        "utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M"),
        "machine": f"{platform.node()}, {platform.machine()}, {__import__('os').cpu_count()} cores"}


def _save(path: Path, doc: dict) -> None:
    from vswrist_gym.agents.fileio import atomic_write_text
    from vswrist_gym.agents.protocol import json_safe

    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(json_safe(doc), indent=1) + "\n")


def result_path(out: Path, env_id: str) -> Path:
    return Path(out) / f"{env_id.split('/')[-1]}.json"


def run_task(env_id: str, out: Path, runs_dir: Path, stage: str = "all", budget: int = BUDGET,
             command: str = "", log=print, train_seeds=NECESSITY_SEEDS) -> dict:
    """Selection, headroom and (``stage`` all or necessity) necessity of one task, each saved as it is done and
    skipped when already in OUT/<Task>-vN.json."""
    path = result_path(out, env_id)
    proto = protocol_block(budget, train_seeds)
    doc = json.loads(path.read_text()) if path.is_file() else {"task": env_id, "protocol": proto}
    if doc["protocol"] != proto:
        raise GateError(f"{path} was made under another protocol ({doc['protocol']}); move it away to start over")
    if command:
        doc.setdefault("commands", [])
        if command not in doc["commands"]:
            doc["commands"].append(command)
    if "selection" not in doc:
        t0 = time.time()
        doc["selection"] = select(env_id)
        _stamp(doc, "selection")
        _save(path, doc)
        log(f"{env_id}: selected s = {doc['selection']['best_constant']:+.1f}, rule levels "
            f"{doc['selection']['rule_levels']} on tuning episodes ({time.time() - t0:.0f} s)")
    if "headroom" not in doc:
        t0 = time.time()
        doc["headroom"] = headroom(env_id, doc["selection"])
        _stamp(doc, "headroom")
        _save(path, doc)
    d = doc["headroom"]["rule_minus_constant"]
    log(f"{env_id}: headroom {d['mean']:+.2f} (s.e. {d['se']:.2f}) on held-out episodes: "
        f"{'passes' if doc['headroom']['passes'] else 'fails'}")
    if stage == "headroom":
        return doc
    if "feedback" not in doc:
        t0 = time.time()
        hr = doc["headroom"]
        doc["feedback"] = feedback(env_id, doc["selection"],
                                   hr["returns"]["constant"][f"{doc['selection']['best_constant']:+.1f}"],
                                   hr["rule_minus_constant"]["mean"])
        _stamp(doc, "feedback")
        _save(path, doc)
        log(f"{env_id}: posture feedback chosen k = {doc['feedback']['k']:g}/s ({time.time() - t0:.0f} s)")
    fb = doc["feedback"]
    log(f"{env_id}: posture feedback {fb['gain']['mean']:+.2f} (s.e. {fb['gain']['se']:.2f}) over the constant, "
        f"share {fb['share']['mean']:+.2f} [{fb['share']['low']:+.2f}, {fb['share']['high']:+.2f}]: "
        f"{'passes' if fb['passes'] else 'fails'}")
    if stage == "feedback":
        return doc
    nec = doc.setdefault("necessity", {"seeds": list(proto["necessity_seeds"]), "budget": int(budget), "runs": {}})
    for s in proto["necessity_seeds"]:
        if str(s) in nec["runs"]:
            continue
        t0 = time.time()
        run_dir = train_posture_only(env_id, doc["selection"]["best_constant"], s, runs_dir, budget, log=log)
        returns = trained_returns(run_dir, env_id)
        nec["runs"][str(s)] = {"run_dir": str(run_dir), "returns": returns, "seconds": round(time.time() - t0, 1)}
        nec["summary"] = necessity_summary(doc)
        _stamp(doc, f"necessity_seed{s}")
        _save(path, doc)
        g = nec["summary"]["gains"][str(s)]
        log(f"{env_id}: posture-only PPO seed {s}: {g['mean']:+.2f} (s.e. {g['se']:.2f}) over the constant")
    nec["summary"] = necessity_summary(doc)
    _save(path, doc)
    sh = nec["summary"]["share"]
    log(f"{env_id}: share of the headroom {sh['mean']:+.2f} [{sh['low']:+.2f}, {sh['high']:+.2f}]: necessity "
        f"{'passes' if nec['summary']['passes'] else 'fails'}")
    return doc


# ------------------------------------------------------------------------------------------------ the table


GATE_HEADER = ("| task | best constant | rule levels (soft, stiff) | constant return | rule - constant (s.e.) "
               "| z | headroom | posture-only PPO gain per seed | share of headroom [95 %] | necessity "
               "| posture feedback: rate, gain (s.e.) | its share [95 %] | feedback | gate |\n"
               "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")


def gate_row(doc: dict) -> str:
    sel, hr = doc["selection"], doc.get("headroom")
    name = f"`{doc['task']}`"
    if hr is None:
        return (f"| {name} | s = {sel['best_constant']:+.1f} | {sel['rule_levels']} | | | | not measured "
                f"| | | | | | | |")
    d = hr["rule_minus_constant"]
    const = float(np.mean(hr["returns"]["constant"][f"{sel['best_constant']:+.1f}"]))
    lo, hi = sel["rule_levels"]
    cells = [name, f"s = {sel['best_constant']:+.1f}", f"{lo:+.1f}, {hi:+.1f}", f"{const:.1f}",
             f"{d['mean']:+.1f} ({d['se']:.1f})", f"{hr['z']:.1f}", "**pass**" if hr["passes"] else "fail"]
    summary = (doc.get("necessity") or {}).get("summary")
    if summary is None:
        cells += ["", "", "not measured"]
    else:
        gains = ", ".join(f"{g['mean']:+.1f}" for g in summary["gains"].values())
        sh = summary["share"]
        share = "n/a (no headroom)" if math.isnan(sh["mean"]) else \
            f"{sh['mean']:+.2f} [{sh['low']:+.2f}, {sh['high']:+.2f}]"
        verdict = "**pass**" if summary["passes"] else ("incomplete" if not summary["complete"] else "fail")
        cells += [gains, share, verdict]
    fb = doc.get("feedback")
    if fb is None:
        cells += ["", "", "not measured"]
    else:
        sh = fb["share"]
        cells += [f"{fb['k']:g}/s, {fb['gain']['mean']:+.1f} ({fb['gain']['se']:.1f})",
                  "n/a (no headroom)" if math.isnan(sh["mean"]) else
                  f"{sh['mean']:+.2f} [{sh['low']:+.2f}, {sh['high']:+.2f}]",
                  "**pass**" if fb["passes"] else "fail"]
    failed = (not hr["passes"] or (summary is not None and summary["complete"] and not summary["passes"])
              or (fb is not None and not fb["passes"]))
    gate = "fail" if failed else ("**pass**" if passes(doc) else "pending")
    cells.append(gate)
    return "| " + " | ".join(cells) + " |"


def gate_table(docs: list[dict]) -> str:
    # the table states the dates only (the JSON files keep the times)
    made = sorted({v["utc"].split(" ")[0] for d in docs for v in d.get("made", {}).values()})
    machines = sorted({v["machine"] for d in docs for v in d.get("made", {}).values()})
    budgets = sorted({d["protocol"]["budget"] for d in docs})
    budget = f" --budget {budgets[0]}" if budgets != [BUDGET] and len(budgets) == 1 else ""
    seeds = sorted({tuple(d["protocol"]["necessity_seeds"]) for d in docs})
    if len(seeds) == 1 and list(seeds[0]) != list(NECESSITY_SEEDS):
        budget += " --train-seeds " + " ".join(map(str, seeds[0]))
    ids = " ".join(d["task"] for d in docs)
    lines = [GATE_HEADER] + [gate_row(d) for d in docs]
    lines += ["", f"`vswrist gate --tasks {ids}{budget}` (`--stage headroom` first, then the rest), "
              f"{' to '.join(dict.fromkeys([made[0], made[-1]])) if made else '?'} on {'; '.join(machines) or '?'} "
              f"(other jobs sharing its cores; the returns do not depend on the load)."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from vswrist_gym import TASKS, resolve_id

    ap = argparse.ArgumentParser(prog="vswrist gate", description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), type=resolve_id,
                    help=f"short names (the newest version) or full ids (default: {' '.join(TASKS)})")
    ap.add_argument("--stage", choices=("headroom", "feedback", "necessity", "all"), default="all",
                    help="headroom: selection and headroom only; feedback: also the posture feedback; necessity "
                         "and all: also the posture-only PPO runs")
    ap.add_argument("--out", default="experiments/gate", help="folder of the per-task JSON results")
    ap.add_argument("--runs-dir", default="runs/gate", help="folder of the posture-only PPO runs (git-ignored)")
    ap.add_argument("--budget", type=int, default=BUDGET, help="env steps per posture-only PPO run")
    ap.add_argument("--train-seeds", type=int, nargs="+", default=list(NECESSITY_SEEDS), metavar="SEED",
                    help=f"training seeds of the posture-only PPO (default {' '.join(map(str, NECESSITY_SEEDS))}); "
                         f"other seeds need another --out, since a result file records its protocol")
    ap.add_argument("--write", default=None, metavar="PATH",
                    help="rewrite the 'gate' generated block of PATH (docs/environments.md) from the JSON files")
    ap.add_argument("--table-only", action="store_true", help="compute nothing: print (and --write) the table")
    ap.add_argument("--shipped", action="store_true",
                    help="instead: every shipped policy against its id's selected constant on the held-out episodes")
    args = ap.parse_args(argv)
    if args.budget < 1:
        ap.error(f"--budget must be a positive number of env steps, got {args.budget}")
    if len(set(args.train_seeds)) < 2 or min(args.train_seeds) < 0:
        ap.error(f"--train-seeds must be at least two distinct seeds >= 0, got {args.train_seeds}")
    ids = list(dict.fromkeys(resolve_id(t) for t in args.tasks))  # argparse leaves a list default unconverted
    out = Path(args.out)
    command = "vswrist gate " + shlex.join(argv if argv is not None else sys.argv[1:])
    from vswrist_gym.agents.procs import limit_threads

    limit_threads(1)
    if args.shipped:
        return shipped_table(out)
    if not args.table_only:
        for env_id in ids:
            try:
                run_task(env_id, out, Path(args.runs_dir), stage=args.stage, budget=args.budget, command=command,
                         log=lambda *a: print(*a, flush=True),  # a log redirected to a file shows progress
                         train_seeds=list(dict.fromkeys(args.train_seeds)))
            except GateError as exc:
                print(f"vswrist gate: {exc}", file=sys.stderr)
                return 2
    return publish("vswrist gate", out, ids, "gate", gate_table, args.write, keep=lambda d: "selection" in d)


def publish(prog: str, out: Path, ids, block: str, make_table, write: str | None, keep=lambda doc: True) -> int:
    """Print the table ``make_table(docs)`` of the result files ``OUT/<Task>-vN.json`` of ``ids`` and, with
    ``write``, rebuild the generated ``block`` of that markdown file; 2 when there is nothing to show."""
    docs = [json.loads(result_path(out, i).read_text()) for i in ids if result_path(out, i).is_file()]
    docs = [d for d in docs if keep(d)]
    if not docs:
        print(f"{prog}: no results in {out} for {' '.join(ids)}", file=sys.stderr)
        return 2
    table = make_table(docs)
    print(table)
    if write:
        from vswrist_gym.tools.table import update

        path = Path(write)
        path.write_text(update(path.read_text(), {block: table}))
        print(f"{path}: {block} block updated")
    return 0


def shipped_table(gate_dir: Path) -> int:
    """Print every shipped policy's held-out paired difference to the best constant; exit 1 if one loses."""
    from vswrist_gym.agents.shipped import shipped

    print("| shipped policy | id | best constant | policy - constant [95 %] | wins | verdict |\n|---|---|---|---|---|---|")
    losers = []
    for task, track in sorted(shipped()):
        r = shipped_against_constant(task, track, gate_dir)
        d = r["difference"]
        verdict = "loses" if r["loses"] else ("beats" if r["ci"][0] > 0 else "no difference shown")
        print(f"| {task}:{track} | `{r['env_id']}` | s = {r['best_constant']:+.1f} | {d['mean']:+.1f} "
              f"[{r['ci'][0]:+.1f}, {r['ci'][1]:+.1f}] | {d['wins']:.0%} | {verdict} |", flush=True)
        losers += [f"{task}:{track}"] if r["loses"] else []
    if losers:
        print(f"vswrist gate: shipped policies that lose to the best constant: {' '.join(losers)}", file=sys.stderr)
    return 1 if losers else 0


if __name__ == "__main__":
    raise SystemExit(main())
