"""``vswrist bench-sim``: simulator speed, measured against a bare ``mj_step`` of the same model in the same run.

Prints, per physics substep: the bare ``mj_step`` (the same wrist without springs and motor low-pass:
``physics="bare"``), the full substep (sinh springs + motor dynamics in the MuJoCo plugin, inside ``mj_step``;
and the Python-callback reference) and their ratio; the
substeps per second and the real-time factor of the default path. ``--sweep`` adds the timestep trade-off:
static-stiffness error against the analytic model, speed, and the loop-closure error under random references:
worst, median and least over seeds, and how it scales with the step.
"""

from __future__ import annotations

import argparse
import platform
import time
from datetime import datetime, timezone

import mujoco
import numpy as np

from ..model import native
from ..model.builder import build_model
from ..params import DEVICE_PRESETS, PRESETS, load_params
from ..sim import WristSim
from ..stiffness import coupler_stiffness, lambda_range, motor_references


def _reference_schedule(sim: WristSim, n: int, seed: int = 0) -> np.ndarray:
    """Random posture targets at the largest preload, one per 0.5 s (the motion the timings are taken on)."""
    rng = np.random.default_rng(seed)
    p = sim.params
    out = []
    for _ in range(n):
        u = rng.uniform(sim.kin.u_min, sim.kin.u_max) * 0.8
        out.append(np.append(motor_references(u, 0.5 * lambda_range(u, p)[1], p), rng.uniform(-2, 2)))
    return np.array(out)


def _time_full(sim: WristSim, refs: np.ndarray, control_dt: float, seconds: float) -> float:
    """Wall seconds per substep of ``WristSim.step`` (springs + motors in the plugin or the callbacks)."""
    sim.reset(lam=0.5 * lambda_range(np.zeros(2), sim.params)[1])
    n_ctrl = int(round(seconds / control_dt))
    per_ref = int(round(0.5 / control_dt))
    wall = 0.0
    for k in range(n_ctrl):
        if k % per_ref == 0:
            sim.set_motor_references(refs[(k // per_ref) % len(refs)])
        t0 = time.perf_counter()
        sim.step(control_dt)
        wall += time.perf_counter() - t0
    return wall / (n_ctrl * int(round(control_dt / sim.timestep)))


# the state both models share: everything but the plugin's (the bare model has none)
_SHARED_STATE = int(mujoco.mjtState.mjSTATE_INTEGRATION) & ~int(mujoco.mjtState.mjSTATE_PLUGIN)


def _bare(sim: WristSim) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The same wrist without springs and setpoint dynamics (``physics="bare"``), with the sim's options."""
    m = build_model(sim.params, physics="bare")
    m.opt.disableflags = sim.model.opt.disableflags
    return m, mujoco.MjData(m)


def _time_paired(sim: WristSim, refs: np.ndarray, control_dt: float, seconds: float
                 ) -> tuple[float, float, list[float]]:
    """Wall seconds per substep (full, bare), alternating window by window so that both see the same load
    from other processes. Full: ``WristSim.step`` (springs + motors in the plugin). Bare: ``mj_step`` of the
    same wrist without them (``physics="bare"``: same bodies, joints, constraints and actuators), from the same
    state at the start of each window."""
    bm, bd = _bare(sim)
    sim.reset(lam=0.5 * lambda_range(np.zeros(2), sim.params)[1])
    nsub = int(round(control_dt / sim.timestep))
    n_ctrl = int(round(seconds / control_dt))
    per_ref = int(round(0.5 / control_dt))
    state = np.empty(mujoco.mj_stateSize(bm, _SHARED_STATE))
    full = bare = 0.0
    ratios = []
    for k in range(n_ctrl):
        if k % per_ref == 0:
            sim.set_motor_references(refs[(k // per_ref) % len(refs)])
        mujoco.mj_getState(sim.model, sim.data, state, _SHARED_STATE)
        mujoco.mj_setState(bm, bd, state, _SHARED_STATE)
        t0 = time.perf_counter()
        sim.step(control_dt)
        t_full = time.perf_counter() - t0
        t0 = time.perf_counter()
        mujoco.mj_step(bm, bd, nsub)
        t_bare = time.perf_counter() - t0
        full += t_full
        bare += t_bare
        ratios.append(t_full / t_bare)
    return full / (n_ctrl * nsub), bare / (n_ctrl * nsub), ratios


def _time_python_loop(sim: WristSim, refs: np.ndarray, control_dt: float, seconds: float) -> float:
    """The naive path: one ``mj_step`` per substep of the bare wrist, NumPy springs into ``qfrc_applied`` (the
    motor low-pass runs in NumPy too, without the speed limit: cheaper, if anything)."""
    m, d = _bare(sim)
    sim.reset(lam=0.5 * lambda_range(np.zeros(2), sim.params)[1])
    state = np.empty(mujoco.mj_stateSize(m, _SHARED_STATE))
    mujoco.mj_getState(sim.model, sim.data, state, _SHARED_STATE)
    mujoco.mj_setState(m, d, state, _SHARED_STATE)
    q1, mot = sim._qadr_q1, sim._qadr_motor[:3]
    v1, vm = m.jnt_dofadr[[m.jnt_qposadr.tolist().index(a) for a in q1]], sim._vadr_motor[:3]
    K2, inv_d0 = 2.0 * sim.params.spring.K, 1.0 / sim.params.spring.delta0
    nsub = int(round(control_dt / sim.timestep))
    n_ctrl = int(round(seconds / control_dt))
    per_ref = int(round(0.5 / control_dt))
    act = sim._act_adr
    tc = sim.params.motor.time_constant
    t0 = time.perf_counter()
    for k in range(n_ctrl):
        if k % per_ref == 0:
            ref = refs[(k // per_ref) % len(refs)]
        for _ in range(nsub):
            tau = -K2 * np.sinh((d.qpos[q1] - d.qpos[mot]) * inv_d0)
            d.qfrc_applied[v1] = tau
            d.qfrc_applied[vm] = -tau
            d.act[act] += (ref - d.act[act]) * (sim.timestep / tc)
            mujoco.mj_step(m, d)
    wall = time.perf_counter() - t0
    return wall / (n_ctrl * nsub)


def speed(preset: str, seconds: float, rounds: int, control_dt: float, with_python: bool) -> dict:
    sim = WristSim(preset, backend="c")
    fallback = WristSim(preset, backend="python") if with_python else None
    native.install("c")  # the reference's callbacks stay out of the plugin's timings
    refs = _reference_schedule(sim, 64)
    res: dict[str, list[float]] = {"bare": [], "full_c": [], "ratio": [], "python_loop": [],
                                   "python_callbacks": []}
    for _ in range(rounds):  # interleaved, so that load from other processes hits all alike; best of rounds
        full, bare, ratios = _time_paired(sim, refs, control_dt, seconds)
        res["full_c"].append(full)
        res["bare"].append(bare)
        res["ratio"] += ratios
        if fallback is not None:
            res["python_loop"].append(_time_python_loop(sim, refs, control_dt / 5, seconds / 5))
            res["python_callbacks"].append(_time_full(fallback, refs, control_dt, seconds / 5))
            native.install("c")
    # the Python paths' ratios: each round's time over the bare time of the same round (a burst of load
    # from other processes then hits both), median over rounds; not the ratio of two bests of rounds
    python_ratios = {k + "_ratio": float(np.median(np.array(res[k]) / np.array(res["bare"])))
                     for k in ("python_loop", "python_callbacks") if res[k]}
    out = {k: min(v) for k, v in res.items() if v}
    out.update(python_ratios)
    out["ratio"] = float(np.median(res["ratio"]))  # median over all paired control windows
    out["ratio_iqr"] = tuple(np.percentile(res["ratio"], [25, 75]))
    out["timestep"] = sim.timestep
    return out


def stiffness_error(params, u, frac: float) -> tuple[float, float]:
    """Relative Frobenius error of the measured static stiffness against the complete analytic one, and the
    paper formula's error against the measurement."""
    lo, hi = lambda_range(u, params)
    lam = frac * (hi if frac > 0 else -lo)
    S_ref = coupler_stiffness(u, lam, params)
    c = 0.3 * np.sqrt(np.linalg.eigvalsh(S_ref).min() * 6e-3)
    sim = WristSim(params.replace(damping={"leg_joint": c}, environment={"gravity": [0.0, 0.0, 0.0]}))
    u = np.asarray(u, float)
    W = sim.kin.coupler_twist_jacobian(u)[:3]
    P = W @ np.linalg.inv(W.T @ W)
    loads, moves = [], []
    for i in range(2):
        w = S_ref @ (2e-3 * np.eye(2)[i])
        ends = []
        for s in (1.0, -1.0):
            sim.reset(u=u, lam=lam)
            sim.apply_wrench(torque=P @ (s * w))
            for _ in range(400):
                sim.step(0.1)
                if np.abs(sim.posture_rate()).max() < 1e-8:
                    break
            ends.append(sim.posture()[:2])
        loads.append(w)
        moves.append((ends[0] - ends[1]) / 2)
    S = np.column_stack(loads) @ np.linalg.inv(np.column_stack(moves))
    S_paper = coupler_stiffness(u, lam, params, include_load_term=False)
    return (float(np.linalg.norm(S - S_ref) / np.linalg.norm(S_ref)),
            float(np.linalg.norm(S_paper - S) / np.linalg.norm(S)))


SEEDS = tuple(range(20))  # random-target sequences of the closure sweep (seed 0: the targets of tests/test_sim.py)
PERTURBATIONS = 10  # runs of seed 0 with the last digits of the preload changed
SWEEP_TIMESTEPS = (0.00025, 0.0005, 0.001, 0.002)  # s; the constraint time constant follows (2 substeps)


def random_reference_run(params, posture_rate: float | None, seconds: float = 10.0, seed: int = 0,
                         preload_scale: float = 1.0) -> dict:
    """Random posture targets (RUD, FE across the range of motion, PS in [-2, 2] rad; a new one every 0.5 s) at
    the largest preload ``lambda_range(u)[1]``, gravity on. ``posture_rate`` (rad/s) limits how fast the
    commanded posture (all three angles) moves towards the target, as a controller would command it; None:
    the references jump to it (the motors saturate). ``preload_scale`` multiplies the preload (1 + 1e-14: a
    change in the last digits, as another CPU's rounding makes).

    Returns the worst loop-closure error after any physics substep (``closure``, m or rad), the largest motor
    torque over its limit (``torque``) and the fastest motor (``speed``, rad/s) at the 20 ms control periods,
    and MuJoCo's warnings (``warnings``). Raises if the state ever turns non-finite."""
    sim = WristSim(params)
    p = sim.params
    substeps = int(round(0.02 / sim.timestep))
    tl = np.array([p.motor.torque_limit] * 3 + [p.motor.ps_torque_limit])
    rng = np.random.default_rng(seed)
    u = np.zeros(2)
    sim.reset(u=u, lam=preload_scale * lambda_range(u, p)[1])
    closure, torque, speed_max, target, ps_target, ps = 0.0, 0.0, 0.0, u, 0.0, 0.0
    for k in range(int(round(seconds / 0.02))):
        if k % 25 == 0:
            target, ps_target = rng.uniform(sim.kin.u_min, sim.kin.u_max), rng.uniform(-2.0, 2.0)
        if posture_rate is None:
            u, ps = target, ps_target
        else:
            step = target - u
            u = u + step * min(1.0, posture_rate * 0.02 / max(float(np.linalg.norm(step)), 1e-12))
            ps += float(np.clip(ps_target - ps, -posture_rate * 0.02, posture_rate * 0.02))
        sim.set_motor_references(np.append(motor_references(u, preload_scale * lambda_range(u, p)[1], p), ps))
        for _ in range(substeps):  # after every substep: the peaks of a jump last a few milliseconds
            sim.step(sim.timestep)
            closure = max(closure, sim.loop_closure_error())
        torque = max(torque, float(np.max(np.abs(sim.motor_torques()) / tl)))
        speed_max = max(speed_max, float(np.abs(sim.motor_velocities()).max()))
        d = sim.data
        if not (np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel)) and np.all(np.isfinite(d.act))):
            raise FloatingPointError(f"non-finite state at t = {sim.time:.3f} s (seed {seed})")
    return {"closure": closure, "torque": torque, "speed": speed_max, "warnings": sim.warnings()}


def closure_spread(params, posture_rate: float | None, seeds=SEEDS) -> dict:
    """random_reference_run over ``seeds``: the closure of each seed, its worst (and which seed), median and
    least, and the fastest motor of all. The spread over seeds stands in for the spread between machines: the
    motion amplifies rounding differences until the peaks fall elsewhere, as a new seed's do."""
    runs = [random_reference_run(params, posture_rate, seed=s) for s in seeds]
    c = np.array([r["closure"] for r in runs])
    return {"closures": c, "worst": float(c.max()), "worst_seed": seeds[int(c.argmax())],
            "median": float(np.median(c)), "least": float(c.min()),
            "speed": max(r["speed"] for r in runs), "warnings": sum(bool(r["warnings"]) for r in runs)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="vswrist bench-sim", description=__doc__)
    parser.add_argument("--params", default=None,
                        help=f"preset ({', '.join(PRESETS)}) or YAML; default: paper and paper_knm")
    parser.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per timing (default 4)")
    parser.add_argument("--rounds", type=int, default=5, help="interleaved timing rounds, best taken (default 3)")
    parser.add_argument("--control-dt", type=float, default=0.02, help="control period of step() calls, s")
    parser.add_argument("--no-python", action="store_true", help="skip the slow Python reference paths")
    parser.add_argument("--sweep", action="store_true", help="also sweep the timestep: accuracy against speed")
    parser.add_argument("--seeds", type=int, default=len(SEEDS),
                        help=f"random-target seeds of the sweep's loop-closure runs (default {len(SEEDS)})")
    parser.add_argument("--solvers", action="store_true",
                        help="also time the full substep under other solvers, Jacobians and integrators")
    args = parser.parse_args(argv)
    presets = [args.params] if args.params else list(DEVICE_PRESETS)
    print(f"vswrist bench-sim  {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC  mujoco {mujoco.__version__}  "
          f"python {platform.python_version()}  {platform.machine()}  {platform.processor() or ''}")
    print("per substep, best of rounds; ratio = full substep / bare mj_step of the same model, same run "
          "(default path: windows alternated, same states)\n")
    for preset in presets:
        r = speed(preset, args.seconds, args.rounds, args.control_dt, not args.no_python)
        dt = r["timestep"]
        print(f"[{preset}] timestep {dt * 1e3:g} ms, step({args.control_dt:g} s) = {round(args.control_dt / dt)} substeps")
        print(f"  bare mj_step                         {r['bare'] * 1e6:8.2f} us   {1 / r['bare']:10.0f} substeps/s")
        print(f"  full, C plugin (default)             {r['full_c'] * 1e6:8.2f} us   {1 / r['full_c']:10.0f} substeps/s   "
              f"ratio {r['ratio']:.3f} (median of paired windows; quartiles {r['ratio_iqr'][0]:.3f}-"
              f"{r['ratio_iqr'][1]:.3f})")
        rows = [("full, Python callbacks (reference)", "python_callbacks"),
                ("Python loop, mj_step per substep", "python_loop")]
        for label, key in rows:
            if key in r:
                print(f"  {label:<36} {r[key] * 1e6:8.2f} us   {1 / r[key]:10.0f} substeps/s   "
                      f"ratio {r[key + '_ratio']:.3f}")
        print(f"  real-time factor (default path)      {dt / r['full_c']:.0f}x\n")
    if args.solvers:
        print("full substep (C plugin) under other MuJoCo settings, same motion; best of rounds, "
              "ratio to the default settings measured alongside")
        for preset in presets:
            sim = WristSim(preset)
            refs = _reference_schedule(sim, 64)
            opt = sim.model.opt
            default = (opt.solver, opt.jacobian, opt.integrator)
            variants = [("default: Newton, dense, implicitfast", default)]
            for solver in (mujoco.mjtSolver.mjSOL_CG, mujoco.mjtSolver.mjSOL_PGS):
                variants.append((f"{solver.name[6:]}, dense, implicitfast", (solver, default[1], default[2])))
            variants.append(("Newton, sparse, implicitfast", (default[0], mujoco.mjtJacobian.mjJAC_SPARSE, default[2])))
            for integ in (mujoco.mjtIntegrator.mjINT_EULER, mujoco.mjtIntegrator.mjINT_IMPLICIT,
                          mujoco.mjtIntegrator.mjINT_RK4):
                variants.append((f"Newton, dense, {integ.name[6:]}", (default[0], default[1], integ)))
            native.install("c")
            for label, (solver, jac, integ) in variants:
                times, base = [], []
                for _ in range(args.rounds):
                    opt.solver, opt.jacobian, opt.integrator = default
                    base.append(_time_full(sim, refs, args.control_dt, args.seconds / 2))
                    opt.solver, opt.jacobian, opt.integrator = solver, jac, integ
                    times.append(_time_full(sim, refs, args.control_dt, args.seconds / 2))
                opt.solver, opt.jacobian, opt.integrator = default
                print(f"  [{preset}] {label:<36} {min(times) * 1e6:7.2f} us  ratio {min(times) / min(base):.2f}")
        print()
    if args.sweep:
        seeds = tuple(range(args.seeds))
        print("timestep sweep (constraint time constant = 2 substeps): stiffness error vs analytic (max over 3 cases),")
        print("paper-formula error, speed")
        spreads = {}
        for preset in presets:
            base = load_params(preset)
            for dt in SWEEP_TIMESTEPS:
                p = base.replace(simulation={"timestep": dt, "constraint_timeconst": 2 * dt})
                errs = [stiffness_error(p, u, f) for u, f in (((0.0, 0.0), 0.9), ((0.5, 0.4), -0.8), ((-0.6, -0.5), 0.3))]
                sim = WristSim(p)
                per = _time_full(sim, _reference_schedule(sim, 64), 0.02, 2.0)
                print(f"  [{preset}] dt {dt * 1e3:5.2f} ms  stiffness err {max(e for e, _ in errs):6.2%}  "
                      f"paper formula {min(e for _, e in errs):5.1%}-{max(e for _, e in errs):5.1%}  "
                      f"{1 / per:7.0f} substeps/s  RTF {dt / per:4.0f}x", flush=True)
                spreads[preset, dt] = {mode: closure_spread(p, rate, seeds)
                                       for mode, rate in (("commanded", 3.0), ("jumps", None))}
        print(f"\nloop closure (m or rad): worst after any substep of 10 s of random targets at the largest preload,")
        print(f"over seeds 0-{seeds[-1]}: worst (its seed) / median / least; commanded posture moving at <= 3 rad/s, "
              "and reference jumps")
        for preset in presets:
            for dt in SWEEP_TIMESTEPS:
                cells = []
                for mode in ("commanded", "jumps"):
                    s = spreads[preset, dt][mode]
                    cells.append(f"{mode} {s['worst']:.2e} (seed {s['worst_seed']:2d}) / {s['median']:.2e} / "
                                 f"{s['least']:.2e}, fastest motor {s['speed']:4.1f} rad/s"
                                 + (f", {s['warnings']} runs with warnings" if s["warnings"] else ""))
                print(f"  [{preset}] dt {dt * 1e3:5.2f} ms  " + "  |  ".join(cells))
            for mode in ("commanded", "jumps"):  # opening ~ dt^k: k from the medians of successive steps
                med = [spreads[preset, dt][mode]["median"] for dt in SWEEP_TIMESTEPS]
                ks = [np.log(b / a) / np.log(t2 / t1) for a, b, t1, t2 in
                      zip(med, med[1:], SWEEP_TIMESTEPS, SWEEP_TIMESTEPS[1:])]
                print(f"  [{preset}] {mode}: median opening ~ dt^k, k = "
                      + ", ".join(f"{k:.1f} ({t1 * 1e3:g}->{t2 * 1e3:g} ms)" for k, t1, t2 in
                                  zip(ks, SWEEP_TIMESTEPS, SWEEP_TIMESTEPS[1:])))
        print(f"\nseed 0 at the preset's step with the preload scaled by 1 + k 1e-14 (k = 0-{PERTURBATIONS - 1}; "
              "rounding as another CPU's): worst / median / least closure")
        for preset in presets:
            for mode, rate in (("commanded", 3.0), ("jumps", None)):
                c = [random_reference_run(load_params(preset), rate, seed=0, preload_scale=1.0 + k * 1e-14)["closure"]
                     for k in range(PERTURBATIONS)]
                print(f"  [{preset}] {mode:<9} {max(c):.2e} / {np.median(c):.2e} / {min(c):.2e}", flush=True)
    return 0


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
