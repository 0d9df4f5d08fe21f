"""Does adapting stiffness within an episode pay off? Constant stiffness against a simple adaptive rule.

``python -m vswrist_gym.tools.probe [--episodes N] [--tasks ...]`` runs, on every task, the reference agent
(command the task's posture reference, ``target``) with each constant stiffness command in
``CONSTANT_COMMANDS`` and with a simple hand-written rule that changes the stiffness within the episode from
what the observation shows (no hidden task state). It prints mean return and success rate of each. A task
"pays for adaptation" when the rule's mean return beats the best constant command.

The rules (observation only):

* LoadHold, Drill: stiff while the posture error shows a load (above ``ERR_ON`` within the last ``HOLD_S``),
  soft otherwise;
* Polish: integral control of the stiffness command on the normal force (stiffer below the band, softer above);
* Impact: stiff in free motion, soft from the first sign of contact until ``IMPACT_SOFT_S`` after the last;
* Insertion: soft, except stiff for ``PUSH_S`` from the first time the fit resists (bottom force above
  ``PUSH_ON``): stiffness only while pushing the pin past the fit.
* Hammer: moderately soft (``HAMMER_SOFT``) until the swing's reference starts to move, then full stiffness:
  the motors need tens of milliseconds to raise the preload, so raising it from the swing's start makes the
  springs stiffen while they are deflected, which adds energy that the strike takes back.
* Throw, and Hammer-v1 (a wind-up before its swing): soft (``THROW_SOFT``) through the wind-up, stiff
  (``THROW_STIFF``) from the step the reference turns forward (the link, lagging, still winds back and loads the
  springs): raising the preload while they are deflected adds energy that the throw or the strike takes back.

Hammer and Throw have no hidden state worth an oracle; their "oracle" column is an optimised open-loop schedule
instead: ``HAMMER_KNOTS`` stiffness commands at fixed times from the swing's start (Throw and Hammer-v1:
``THROW_KNOTS`` from the reference's turn at the end of the wind-up), linear between, optimised with scipy (Powell) on training seeds (from
``TRAIN_SEED0``) and evaluated on the probe's held-out seeds. ``--headroom`` prints the headroom table of docs/environments.md.

``--success`` prints instead, per task, the success rate (and mean return) of agents that should not succeed
next to those that may: uniform random and bang-bang (+-1) actions in the default ``posture_stiffness`` mode
and in the ``residual`` mode, the zero residual action (the analytic baseline at the task's
``residual.stiffness_nominal``), every constant stiffness, the rule and the oracle. A success criterion that
means what its task means gives the flailing agents no more success than the baseline
(``tests/test_success.py``).
"""

from __future__ import annotations

import argparse
import logging

import numpy as np

from vswrist_gym import LATEST, TASKS, newest_task_name

logger = logging.getLogger(__name__)

CONSTANT_COMMANDS = (-1.0, -0.5, 0.0, 0.5, 1.0)
ERR_ON = 0.03   # rad
# Force thresholds and gains are fractions of the task's own force settings, so that the rules carry over to task
# variants whose loads are scaled to another device (vswrist_gym.envs.variants); the default tasks get 2 N, 0.5 N
# and 0.02 /N.
PUSH_ON = 1.0 / 3.0   # Insertion rule: the fit resists (bottom force above this x task.fit_force[0]) ...
PUSH_S = 0.6    # s, ... and the rule is stiff this long from then
ORACLE_LOW = 0.0  # stiffness command of the oracle when the task needs no stiffness (the soft end rings)
IMPACT_FREE = 1.0    # Impact rule and oracle: stiffness command in free motion
IMPACT_SOFT_S = 0.3  # s, the Impact rule stays soft this long after the last contact
IMPACT_TOUCH = 0.02  # Impact rule: a contact is felt above this x task.success_force
POLISH_GAIN = 0.04   # Polish rule: integral gain, stiffness command per N of force error x task.force_tolerance
IMPACT_MARGIN = 0.1  # Impact oracle: soft from this fraction of the path before the (hidden) wall
SLEW = 4.0      # 1/s, largest rate of change of the stiffness command (full range in 0.5 s)
HOLD_S = 0.5    # s, LoadHold/Drill stay stiff this long after the error last exceeded ERR_ON
HAMMER_SOFT = -0.5   # Hammer rule: stiffness command before the swing starts (full stiffness from then)
HAMMER_KNOTS = (0.0, 0.03, 0.06, 0.09, 0.12, 0.15)  # s after the swing's start: knots of the optimised schedule
TRAIN_SEED0 = 100    # training seeds of the optimised schedule: TRAIN_SEED0, ... (the probe's start at 1000)
THROW_SOFT = -1.0    # Throw rule: stiffness command through the wind-up ...
THROW_STIFF = 1.0    # ... and from the reference's turn on (chosen on training seeds 100-111 among 0.5, 0.75, 1)
THROW_KNOTS = (-0.06, -0.03, 0.0, 0.03, 0.06, 0.09)  # s from the reference's turn: knots of Throw's schedule


def _slew(state: dict, s: float, dt: float) -> float:
    """Move ``state["cmd"]`` towards ``s`` at most ``SLEW`` per second (a jump in preload shakes the lightly damped
    wrist) and return it; the first call starts at ``s``."""
    cmd = state.get("cmd", s)
    step = SLEW * dt
    state["cmd"] = cmd + float(np.clip(s - cmd, -step, step))
    return state["cmd"]


def adaptive_policy(env):
    """A stateful function obs -> action implementing the task's rule (see the module docstring)."""
    u = env.unwrapped
    sl = u.obs_slices
    task = u.task
    state = {"s": 0.0, "hold": 0, "soft": 0, "push": None}
    hold_steps = int(round(HOLD_S / u.ctrl_dt))
    push_steps = int(round(PUSH_S / u.ctrl_dt))
    impact_soft = int(round(IMPACT_SOFT_S / u.ctrl_dt))
    tp = u.tp

    def act(obs):
        obs = np.asarray(obs, dtype=float)
        target = obs[sl["target"]]
        err = float(np.linalg.norm((obs[sl["posture"]] - target)[:2]))
        contact = float(obs[sl["contact_force"]][0]) if "contact_force" in sl else 0.0
        if task in ("load_hold", "drill"):
            state["hold"] = hold_steps if err > ERR_ON else max(state["hold"] - 1, 0)
            s = 1.0 if state["hold"] > 0 else -1.0
        elif task == "polish":
            goal = float(obs[sl["force_target"]][0])
            gain = POLISH_GAIN / tp["force_tolerance"]
            state["s"] = float(np.clip(state["s"] + gain * (goal - contact), -1.0, 1.0))
            s = state["s"]
        elif task == "hammer" and not u.windup:
            state["go"] = state.get("go", False) or u._t >= u.tp["swing_start_s"] - 1e-9
            return u.reference_to_action(target, 1.0 if state["go"] else HAMMER_SOFT)
        elif task in ("throw", "hammer"):  # Throw, and Hammer with a wind-up
            # the reference has turned forward: its FE grew since the last step
            prev = state.get("fe")
            state["go"] = state.get("go", False) or (prev is not None and target[1] > prev + 1e-9)
            state["fe"] = float(target[1])
            return u.reference_to_action(target, THROW_STIFF if state["go"] else THROW_SOFT)
        elif task == "impact":
            # stiff in free motion (the heavy tool's sag costs tracking), soft as soon as and for as long as the
            # touch sensor shows a contact, and for IMPACT_SOFT_S after it
            touch = IMPACT_TOUCH * tp["success_force"]
            state["soft"] = impact_soft if contact > touch else max(state["soft"] - 1, 0)
            s = -1.0 if state["soft"] > 0 else IMPACT_FREE
        else:  # insertion: count down from the first push on the fit
            if state["push"] is None and float(obs[sl["bottom_force"]][0]) > PUSH_ON * tp["fit_force"][0]:
                state["push"] = push_steps
            elif state["push"]:
                state["push"] -= 1
            s = 1.0 if state["push"] else -1.0
        return u.reference_to_action(target, _slew(state, s, u.ctrl_dt))
    return act


def oracle_policy(env):
    """Soft/stiff from the hidden task state (event times, wall position, depth): what adapting is worth with
    perfect knowledge."""
    u = env.unwrapped
    task = u.task
    state = {}

    if task in ("hammer", "throw"):
        return schedule_policy(env, optimised_schedule(u.spec.id, u._user_config))

    def act(obs):
        t = u._t
        if task == "load_hold":
            # after the onset, as stiff as the (hidden) load needs: full stiffness for the heaviest load
            heavy = u._mass / u.tp["load_mass"][1]
            s = -1.0 + 2.0 * min(1.0, heavy) if t >= u._onset else ORACLE_LOW
        elif task == "drill":
            s = 1.0 if u._t_on - 0.1 <= t < u._t_off else ORACLE_LOW
        elif task == "insertion":
            # stiff from just before the pin reaches the fit (2 mm) until it has pushed the fit plate three quarters
            # of its way down (past the success depth), soft otherwise
            near = u.pin_depth() >= u.tp["fit_depth"] * u.tp["hole_depth"] - 0.002
            s = 1.0 if near and u.fit_travel() < 0.75 else -1.0
        elif task == "impact":
            # knows where the wall stands: soft from shortly before it until the reference is back behind it,
            # stiffer in free motion (and throughout when there is no wall)
            f = (u._target[1] - u._fe0) / (u._fe1 - u._fe0)  # fraction of the path the reference is at
            s = -1.0 if u._obstacle and f >= u._frac - IMPACT_MARGIN else IMPACT_FREE
        else:  # polish: the stiffness whose force matches the target, from the measured force (integral rule)
            return adaptive(obs)
        return u.reference_to_action(u._target, _slew(state, s, u.ctrl_dt))
    adaptive = adaptive_policy(env)
    return act


def _turns(u) -> bool:
    """Whether the task's reference winds up and turns (Throw, Hammer-v1): its schedules start from the turn."""
    return u.task == "throw" or (u.task == "hammer" and u.windup)


def schedule_knots(u) -> np.ndarray:
    """The times (s, episode time) of the open-loop schedule's knots: ``HAMMER_KNOTS`` after Hammer's swing
    start (``task.swing_start_s``), ``THROW_KNOTS`` after Throw's turn (the reference leaves ``task.fe_back``)."""
    if _turns(u):
        return np.asarray(THROW_KNOTS) + u._swing_t0
    return np.asarray(HAMMER_KNOTS) + u.tp["swing_start_s"]


def schedule_policy(env, values):
    """Open-loop stiffness schedule on the task's reference: command ``values[k]`` at the k-th knot
    (``schedule_knots``), linear between, the first before and the last after."""
    u = env.unwrapped
    sl = u.obs_slices["target"]
    values = np.clip(np.asarray(values, dtype=float), -1.0, 1.0)
    return lambda obs: u.reference_to_action(np.asarray(obs)[sl], float(np.interp(u._t, schedule_knots(u), values)))


_SCHEDULES: dict = {}


def optimised_schedule(env_id: str, config: dict | None = None, train_seeds: int = 6, maxfev: int = 160) -> tuple:
    """The open-loop schedule (one value per knot, ``schedule_knots``) that maximises the mean return over ``train_seeds``
    training episodes (seeds ``TRAIN_SEED0`` ...), by scipy's Powell method from the best constant command,
    at most ``maxfev`` evaluations; cached per (id, config, seeds, maxfev)."""
    import gymnasium as gym
    from scipy.optimize import minimize

    key = (env_id, repr(sorted((config or {}).items())), train_seeds, maxfev)
    if key in _SCHEDULES:
        return _SCHEDULES[key]
    env = gym.make(env_id, config=dict(config or {}))
    seeds = range(TRAIN_SEED0, TRAIN_SEED0 + train_seeds)
    n = len(THROW_KNOTS if _turns(env.unwrapped) else HAMMER_KNOTS)

    def loss(x):
        return -evaluate(env, lambda: schedule_policy(env, x), seeds)[0]

    starts = {c: loss(np.full(n, c)) for c in CONSTANT_COMMANDS}
    x0 = np.full(n, min(starts, key=starts.get))
    res = minimize(loss, x0, method="Powell", bounds=[(-1.0, 1.0)] * n,
                   options={"maxfev": maxfev, "xtol": 0.02, "ftol": 1e-3})
    env.close()
    _SCHEDULES[key] = tuple(float(v) for v in np.clip(res.x, -1.0, 1.0))
    return _SCHEDULES[key]


def within(policy, levels: tuple[float, float]):
    """``policy`` with its stiffness command (the last action entry, mode ``posture_stiffness``) mapped linearly
    from [-1, 1] onto ``levels`` = (soft, stiff): the rule's or oracle's soft and stiff ends moved inside the
    command range, for a device whose softest commands cannot hold the posture (the literal ``paper`` springs)."""
    lo, hi = levels
    if (lo, hi) == (-1.0, 1.0):
        return policy

    def act(obs):
        a = np.array(policy(obs), dtype=np.float32)
        a[-1] = lo + 0.5 * (float(a[-1]) + 1.0) * (hi - lo)
        return a
    return act


def constant_policy(env, s: float):
    u = env.unwrapped
    sl = u.obs_slices["target"]
    return lambda obs: u.reference_to_action(np.asarray(obs)[sl], s)


def random_policy(env, rng: np.random.Generator, bang_bang: bool = False):
    """Uniform random actions in [-1, 1] (``bang_bang``: each entry -1 or +1 with equal chance), drawn from ``rng``."""
    shape = env.action_space.shape
    if bang_bang:
        return lambda obs: np.where(rng.random(shape) < 0.5, -1.0, 1.0).astype(np.float32)
    return lambda obs: rng.uniform(-1.0, 1.0, shape).astype(np.float32)


def evaluate(env, policy_factory, seeds, terms: dict | None = None, returns: list | None = None,
             on_end=None) -> tuple[float, float]:
    """Mean return and success rate over ``seeds``; if ``terms`` is a dict, it receives the mean episode sum of
    every weighted reward term (``reward_<name>`` of ``info``); if ``returns`` is a list, each episode's return;
    ``on_end(env, info)`` is called at the end of each episode."""
    totals, successes, sums = [], [], {}
    for seed in seeds:
        policy = policy_factory()
        obs, _ = env.reset(seed=int(seed))
        total, done = 0.0, False
        while not done:
            obs, r, term, trunc, info = env.step(policy(obs))
            total += r
            done = term or trunc
            for k, v in info.items():
                if k.startswith("reward_"):
                    sums[k[7:]] = sums.get(k[7:], 0.0) + v
        totals.append(total)
        successes.append(info["is_success"])
        if on_end is not None:
            on_end(env, info)
    if terms is not None:
        terms.update({k: v / len(totals) for k, v in sums.items()})
    if returns is not None:
        returns.extend(totals)
    return float(np.mean(totals)), float(np.mean(successes))


def probe(task: str, episodes: int, seed0: int = 1000, config: dict | None = None, oracle: bool = True,
          levels: tuple[float, float] = (-1.0, 1.0)) -> dict:
    """Every constant command, the rule and (``oracle``) the oracle or, for Hammer, the optimised schedule (whose
    optimisation takes minutes) on episodes ``seed0 ...``: mean return and success rate, per-episode returns, and
    paired differences to the best constant. ``levels``: the rule's and the oracle's stiffness commands mapped
    from [-1, 1] onto [soft, stiff] (``within``)."""
    import gymnasium as gym

    import vswrist_gym  # noqa: F401

    env = gym.make(LATEST.get(task, task), config=config or {})  # a short name (the newest version) or an id
    seeds = range(seed0, seed0 + episodes)
    out = {"task": task, "constant": {}, "terms": {}, "returns": {}}

    def run(label, factory):
        speeds = out.setdefault("impact_speed", {}).setdefault(label, [])
        rigid = out.setdefault("rigid_speed", [])

        def end(env_, info):  # Hammer: the strike's normal speed (nan: no strike) and the rigid bound, m/s
            if "impact_speed" in info:
                speeds.append(info["impact_speed"] if info["struck"] else float("nan"))
            elif "release_speed" in info:  # Throw: the release speed (nan: no release)
                speeds.append(info["release_speed"] if info["released"] else float("nan"))
            else:
                return
            if label == "rule":
                rigid.append(info["rigid_speed"])
        return evaluate(env, factory, seeds, out["terms"].setdefault(label, {}), out["returns"].setdefault(label, []),
                        on_end=end)

    for s in CONSTANT_COMMANDS:
        out["constant"][s] = run(f"s={s:+.1f}", lambda s=s: constant_policy(env, s))
    out["adaptive"] = run("rule", lambda: within(adaptive_policy(env), levels))
    if oracle:
        out["oracle"] = run("oracle", lambda: within(oracle_policy(env), levels))
    best = max(out["constant"], key=lambda s: out["constant"][s][0])
    out["best_constant"] = best
    out["gain"] = out["adaptive"][0] - out["constant"][best][0]
    if oracle:
        out["oracle_gain"] = out["oracle"][0] - out["constant"][best][0]
    # the same episodes for every agent: per-episode differences to the best constant remove the episode spread
    ref = np.array(out["returns"][f"s={best:+.1f}"])
    out["paired"] = {}
    for label in ("rule", "oracle") if oracle else ("rule",):
        d = np.array(out["returns"][label]) - ref
        se = float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("nan")
        out["paired"][label] = (float(d.mean()), se, float(np.mean(d > 0.0)))
    env.close()
    if not out["rigid_speed"]:
        del out["impact_speed"], out["rigid_speed"]
    return out


HEADROOM_HEADER = ("| task | best constant | return | rule | rule - best (s.e.) | schedule | schedule - best (s.e.) |\n"
                   "|---|---|---|---|---|---|---|")


def headroom_rows(results) -> list[str]:
    """Markdown rows of the headroom table from ``probe`` results: the best constant's mean return, the rule's and
    the schedule's (Hammer: the optimised open-loop schedule; the others: the hidden-state oracle), each with its
    paired mean difference to the best constant and the standard error of that mean."""
    rows = []
    for r in results:
        best = r["best_constant"]
        sched = "optimised" if r["task"] in ("Hammer", "Throw") else "oracle"
        (rm, rse, _), (om, ose, _) = r["paired"]["rule"], r["paired"]["oracle"]
        rows.append(f"| {r['task']} | s = {best:+.1f} | {r['constant'][best][0]:.1f} | {r['adaptive'][0]:.1f} | "
                    f"{rm:+.1f} ({rse:.1f}) | {sched} {r['oracle'][0]:.1f} | {om:+.1f} ({ose:.1f}) |")
    return rows


def headroom_json(results, episodes: int, seed0: int) -> dict:
    """The headroom table as `vswrist aggregate --headroom` reads it: per task, the larger of the rule's and the
    schedule's paired gain over the best constant (the normalised score's 1); tasks where neither gains are left
    out, since no score can be normalised against them."""
    tasks = {}
    for r in results:
        (rm, rse, _), (om, ose, _) = r["paired"]["rule"], r["paired"]["oracle"]
        gain = max(rm, om)
        if gain > 0:
            tasks[r["task"]] = {"headroom": float(gain), "best_constant": float(r["best_constant"]),
                                "rule": [float(rm), float(rse)], "schedule": [float(om), float(ose)],
                                "by": "rule" if rm >= om else ("optimised" if r["task"] in ("Hammer", "Throw") else "oracle")}
    return {"episodes": episodes, "seed0": seed0, "tasks": tasks}


def hammer_speed_lines(r) -> list[str]:
    """Mean strike speed (m/s) per agent next to the rigid bound, from a Hammer ``probe`` result."""
    rigid = float(np.mean(r["rigid_speed"]))
    best = f"s={r['best_constant']:+.1f}"
    ref = np.array(r["impact_speed"][best])
    lines = [f"rigid bound (motor speed limit x lever) {rigid:.2f} m/s, mean over the episodes; strikes: episodes "
             f"with a strike (late ones included; nan speeds are misses)"]
    for label, v in r["impact_speed"].items():
        v = np.array(v)
        d = v - ref
        ok = np.isfinite(d)
        line = f"{label:<8} {np.nanmean(v) if np.isfinite(v).any() else float('nan'):6.2f} m/s"
        if np.isfinite(v).any():
            line += f"  = {np.nanmean(v) / rigid:4.2f} x rigid"
        if ok.sum() > 1:
            se = float(np.std(d[ok], ddof=1) / np.sqrt(ok.sum()))
            line += (f"  vs best constant {d[ok].mean() / ref[ok].mean():+6.1%} (paired {d[ok].mean():+.2f} "
                     f"({se:.2f}) m/s)")
        lines.append(line + f", strikes {np.isfinite(v).sum()}/{len(v)}")
    return lines


def success_probe(task: str, episodes: int, seed0: int = 1000, config: dict | None = None) -> dict:
    """Success rate and mean return, {agent: (rate, return)}, of flailing agents, the analytic baseline, every
    constant stiffness, the rule and the oracle on episodes ``seed0 .. seed0 + episodes - 1`` (the random agents
    draw their actions from ``numpy.random.default_rng(seed0)``)."""
    import gymnasium as gym

    import vswrist_gym  # noqa: F401

    config = dict(config or {})
    env = gym.make(LATEST[task], config=config)
    res = gym.make(LATEST[task], config={**config, "action_mode": "residual"})
    seeds = range(seed0, seed0 + episodes)
    out, insertion = {}, {}

    def run(label, e, factory):
        if task != "Insertion":
            out[label] = evaluate(e, factory, seeds)[::-1]
            return
        # Insertion: per episode, whether the pin's end reached the success depth at any step (what a depth-only
        # criterion counts), whether it is seated at the end, and the episode's peak wall force (N)
        u, rows = e.unwrapped, insertion.setdefault(label, [])

        def tracked():
            policy, deepest = factory(), [0.0]
            rows.append(deepest)

            def act(obs):
                deepest[0] = max(deepest[0], u.pin_depth())
                return policy(obs)
            return act

        def end(env_, info):
            deepest = max(rows[-1][0], u.pin_depth())
            rows[-1] = (deepest >= u.tp["success_depth"] * u.tp["hole_depth"], u.seated(), info["peak_contact_force"])
        out[label] = evaluate(e, tracked, seeds, on_end=end)[::-1]

    for label, e, bang in (("random", env, False), ("bang-bang", env, True),
                           ("random (residual)", res, False), ("bang-bang (residual)", res, True)):
        rng = np.random.default_rng(seed0)
        run(label, e, lambda e=e, b=bang: random_policy(e, rng, b))
    zero = np.zeros(res.action_space.shape, dtype=np.float32)
    run("zero (residual) = baseline", res, lambda: (lambda obs: zero))
    for c in CONSTANT_COMMANDS:
        run(f"s={c:+.1f}", env, lambda c=c: constant_policy(env, c))
    run("rule", env, lambda: adaptive_policy(env))
    run("oracle", env, lambda: oracle_policy(env))
    env.close()
    res.close()
    if insertion:
        out["_insertion"] = insertion
    return out


TRIM_LEVELS = (-1.0, -0.5, 0.0, 0.5, 1.0)  # residual FE actions of the posture trims (x residual.posture_scale rad)
TRIM_S = 0.08  # s: the trims' middle segment, from the schedule's origin (Hammer's swing start, Throw's turn)


def trim_policy(env, levels):
    """Open-loop posture trim in mode ``residual`` (the stiffness at the baseline's ``residual.stiffness_nominal``):
    FE residual ``levels[0]`` before the schedule's origin (``schedule_knots``' zero: Hammer's swing start, Throw's
    turn), ``levels[1]`` for ``TRIM_S`` from it, ``levels[2]`` after."""
    u = env.unwrapped
    origin = (THROW_KNOTS if _turns(u) else HAMMER_KNOTS)[0]

    def act(obs):
        t0 = float(schedule_knots(u)[0]) - origin  # the episode's (made at its reset, after this factory ran)
        a = np.zeros(env.action_space.shape, dtype=np.float32)
        a[1] = levels[0] if u._t < t0 else (levels[1] if u._t < t0 + TRIM_S else levels[2])
        return a
    return act


def posture_trims(task: str, episodes: int, seed0: int = 1000, config: dict | None = None,
                  train_seeds: int = 8) -> dict:
    """Can a posture trim stand in for the stiffness? At the task's baseline stiffness (its best constant,
    ``residual.stiffness_nominal``), every open-loop FE trim of three segments (``trim_policy``, levels
    ``TRIM_LEVELS``, 125 trims) on ``train_seeds`` training episodes (from ``TRAIN_SEED0``); the best one's paired difference
    to the zero trim on the held-out episodes ``seed0 ...``: (mean, standard error), with its levels. Hammer and
    Throw only (their schedules have an origin in time)."""
    import itertools

    import gymnasium as gym

    import vswrist_gym  # noqa: F401

    if task not in ("Hammer", "Throw"):
        raise ValueError(f"posture trims are defined for Hammer and Throw, not {task}")
    env = gym.make(LATEST[task], config={**(config or {}), "action_mode": "residual"})
    train = range(TRAIN_SEED0, TRAIN_SEED0 + train_seeds)
    scores = {lv: evaluate(env, lambda lv=lv: trim_policy(env, lv), train)[0]
              for lv in itertools.product(TRIM_LEVELS, repeat=3)}
    best = max(scores, key=scores.get)
    held = range(seed0, seed0 + episodes)
    zero, trim = [], []
    evaluate(env, lambda: trim_policy(env, (0.0, 0.0, 0.0)), held, returns=zero)
    evaluate(env, lambda: trim_policy(env, best), held, returns=trim)
    env.close()
    d = np.array(trim) - np.array(zero)
    return {"levels": best, "paired": (float(d.mean()), float(d.std(ddof=1) / np.sqrt(len(d))))}


def print_success(tasks, episodes: int, seed0: int, config: dict) -> None:
    import gymnasium as gym

    import vswrist_gym  # noqa: F401

    print(f"success rate (mean return) over {episodes} episodes (seeds from {seed0}); the baseline is the zero "
          "residual action, the analytic agent at the task's residual.stiffness_nominal")
    results = {t: success_probe(t, episodes, seed0=seed0, config=config) for t in tasks}
    print(f"{'agent':<27}" + "".join(f"{t:>19}" for t in tasks))
    for agent in [a for a in next(iter(results.values())) if not a.startswith("_")]:
        print(f"{agent:<27}" + "".join(f"{results[t][agent][0]:>8.2f} ({results[t][agent][1]:>7.1f})" for t in tasks))
    if "Insertion" in results:
        print("\nInsertion, per agent: episodes whose pin reached the success depth at some step (a depth-only "
              "criterion's successes), episodes seated at the end, and the peak wall force (N) of the seated ones")
        print(f"{'agent':<27}{'reached':>9}{'seated':>8}{'wall force min':>16}{'max':>10}")
        for agent, rows in results["Insertion"]["_insertion"].items():
            peaks = [p for _, seated, p in rows if seated]
            lo, hi = (f"{min(peaks):.1f}", f"{max(peaks):.1f}") if peaks else ("-", "-")
            print(f"{agent:<27}{sum(r for r, _, _ in rows):>5}/{len(rows):<3}{sum(s for _, s, _ in rows):>4}/"
                  f"{len(rows):<3}{lo:>16}{hi:>10}")
    for t in tasks:
        env = gym.make(LATEST[t], config=config)
        print(f"{t}: {env.unwrapped.success_description()}; baseline s={env.unwrapped.cfg['residual']['stiffness_nominal']:+.1f}")
        env.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed0", type=int, default=1000, help="first episode seed (episodes seed0, seed0 + 1, ...)")
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), type=newest_task_name,
                    help=f"short names or full ids (default all: {' '.join(TASKS)})")
    ap.add_argument("--energy-weight", type=float, default=None, help="override reward.energy")
    ap.add_argument("--terms", action="store_true",
                    help="also print, per task, each agent's mean episode sum of every weighted reward term")
    ap.add_argument("--success", action="store_true",
                    help="print instead each task's success rate for random, bang-bang and zero residual actions, "
                         "every constant stiffness, the rule and the oracle")
    ap.add_argument("--params", default=None, help="device preset (params), e.g. paper_knm or paper, or a YAML path")
    ap.add_argument("--config", default=None, metavar="JSON",
                    help='environment settings merged into every task\'s, e.g. \'{"task": {"swing_speed": 0.5}}\'')
    ap.add_argument("--variant", default=None, metavar="PRESET",
                    help="run each task's variant on device preset PRESET with its loads scaled to it "
                         "(configs/envs/variants/PRESET_<task>.yaml, vswrist_gym.envs.variants); --config and "
                         "--params apply on top")
    ap.add_argument("--levels", nargs=2, type=float, default=(-1.0, 1.0), metavar=("SOFT", "STIFF"),
                    help="map the rule's and the oracle's stiffness commands from [-1, 1] onto [SOFT, STIFF]")
    ap.add_argument("--headroom", action="store_true",
                    help="print the headroom table (markdown) and Hammer's strike speeds after the usual tables")
    ap.add_argument("--write", default=None, metavar="PATH",
                    help="with --headroom: rewrite the 'headroom' generated block of PATH (docs/environments.md); "
                         "with --variant V, the 'headroom-V' block")
    ap.add_argument("--headroom-json", default=None, metavar="PATH",
                    help="with --headroom: also write the table as JSON for `vswrist aggregate --headroom`")
    ap.add_argument("--trims", action="store_true",
                    help="print instead, for Hammer and Throw, the best open-loop posture trim at the best constant "
                         "stiffness (chosen on training seeds) against no trim, on the held-out episodes")
    args = ap.parse_args(argv)
    config = {} if args.energy_weight is None else {"reward": {"energy": args.energy_weight}}
    if args.config is not None:
        import json
        config.update(json.loads(args.config))
    if args.params is not None:
        config["params"] = args.params
    if not -1.0 <= args.levels[0] <= args.levels[1] <= 1.0:
        ap.error(f"--levels {args.levels[0]:g} {args.levels[1]:g}: need -1 <= SOFT <= STIFF <= 1")
    configs = {t: config for t in args.tasks}
    if args.variant is not None:
        from ..envs.config import EnvConfigError, merge
        from ..envs.variants import variant_config
        try:
            configs = {t: merge(variant_config(t, args.variant), config) for t in args.tasks}
        except EnvConfigError as exc:
            ap.error(str(exc))
    if args.trims:
        print(f"open-loop posture trims (residual FE levels before / {TRIM_S:g} s from / after the origin) at the "
              f"baseline stiffness, best of {len(TRIM_LEVELS) ** 3} on training seeds from {TRAIN_SEED0}; paired "
              f"against no trim over {args.episodes} episodes (seeds from {args.seed0})")
        for t in args.tasks:
            r = posture_trims(t, args.episodes, seed0=args.seed0, config=configs[t])
            m, se = r["paired"]
            print(f"{t:<11} trim {tuple(r['levels'])}  {m:+.1f} ({se:.1f})")
        return 0
    if args.success:
        if args.variant is not None:
            ap.error("--variant is not supported with --success")
        print_success(args.tasks, args.episodes, args.seed0, config)
        return 0
    cols = "".join(f"{'s=' + format(s, '+.1f'):>16}" for s in CONSTANT_COMMANDS)
    print(f"mean return (success rate) over {args.episodes} episodes (seeds from {args.seed0}), reference agent")
    print(f"{'task':<11}{cols}{'rule':>16}{'oracle':>16}{'rule-best':>10}{'oracle-best':>12}")
    results = []
    for task in args.tasks:
        r = probe(task, args.episodes, seed0=args.seed0, config=configs[task], levels=tuple(args.levels))
        cells = "".join(f"{r['constant'][s][0]:>9.1f} ({r['constant'][s][1]:.1f})" for s in CONSTANT_COMMANDS)
        print(f"{task:<11}{cells}{r['adaptive'][0]:>9.1f} ({r['adaptive'][1]:.1f}){r['oracle'][0]:>9.1f} "
              f"({r['oracle'][1]:.1f}){r['gain']:>+10.1f}{r['oracle_gain']:>+12.1f}")
        results.append(r)
    print("\npaired, episode by episode, against the best constant: mean difference (standard error), share of "
          "episodes where it is higher")
    for r in results:
        cells = "".join(f"{k:>8} {m:+7.1f} ({se:.1f}) {pos:4.0%}" for k, (m, se, pos) in r["paired"].items())
        print(f"{r['task']:<11} best s={r['best_constant']:+.1f}{cells}")
    if args.terms:
        for r in results:
            names = list(next(iter(r["terms"].values())))
            print(f"\n{r['task']}: mean episode sum of each weighted reward term")
            print(f"{'agent':<8}" + "".join(f"{n:>14}" for n in names))
            for agent, t in r["terms"].items():
                print(f"{agent:<8}" + "".join(f"{t[n]:>14.1f}" for n in names))
    for r in results:
        if "impact_speed" in r:
            what = "release speed" if r["task"] == "Throw" else "normal strike speed"
            print(f"\n{r['task']}: {what} (held-out seeds from {args.seed0}; Throw: strikes = releases)")
            print("\n".join(hammer_speed_lines(r)))
    if args.headroom:
        table = HEADROOM_HEADER + "\n" + "\n".join(headroom_rows(results))
        print("\n" + table)
        if args.write:
            from pathlib import Path

            from .table import update
            path = Path(args.write)
            block = "headroom" if args.variant is None else f"headroom-{args.variant}"
            path.write_text(update(path.read_text(), {block: table}))
            logger.info(f"{path}: {block} block updated")
        if args.headroom_json:
            import json
            from pathlib import Path

            doc = headroom_json(results, args.episodes, args.seed0)
            Path(args.headroom_json).write_text(json.dumps(doc, indent=1) + "\n")
            logger.info(f"wrote {args.headroom_json}: {len(doc['tasks'])} tasks")
    return 0


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
