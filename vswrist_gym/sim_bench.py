"""``vswrist bench-sim``: simulator speed, measured against a bare ``mj_step`` of the same model in the same run.

Prints, per physics substep: the bare ``mj_step`` (no springs, no motor low-pass: the callbacks removed), the
full substep (sinh springs + motor dynamics + ``mj_step``) on each implementation, and their ratio; the
substeps per second and the real-time factor of the default path. ``--sweep`` adds the timestep trade-off:
static-stiffness error against the analytic model, worst loop-closure error under random references, speed.
"""

from __future__ import annotations

import argparse
import platform
import time
from datetime import datetime, timezone

import mujoco
import numpy as np

from .model import native
from .params import DEVICE_PRESETS, PRESETS, load_params
from .sim import WristSim
from .stiffness import coupler_stiffness, lambda_range, motor_references


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
    """Wall seconds per substep of ``WristSim.step`` (springs + motors in the callbacks)."""
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


def _time_paired(sim: WristSim, refs: np.ndarray, control_dt: float, seconds: float
                 ) -> tuple[float, float, list[float]]:
    """Wall seconds per substep (full, bare), alternating window by window so that both see the same load
    from other processes. Full: ``WristSim.step`` (springs + motors in the callbacks). Bare: ``mj_step`` of the
    same model and data from the same state, callbacks removed; then the full run continues where it was."""
    backend = native.backend()
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    m, d = sim.model, sim.data
    sim.reset(lam=0.5 * lambda_range(np.zeros(2), sim.params)[1])
    nsub = int(round(control_dt / sim.timestep))
    n_ctrl = int(round(seconds / control_dt))
    per_ref = int(round(0.5 / control_dt))
    full = bare = 0.0
    ratios = []
    for k in range(n_ctrl):
        if k % per_ref == 0:
            sim.set_motor_references(refs[(k // per_ref) % len(refs)])
        before = sim.get_state()
        t0 = time.perf_counter()
        sim.step(control_dt)
        t_full = time.perf_counter() - t0
        after = sim.get_state()
        native.uninstall()
        mujoco.mj_setState(m, d, before, spec)
        t0 = time.perf_counter()
        mujoco.mj_step(m, d, nsub)
        t_bare = time.perf_counter() - t0
        native.install(backend or "auto")
        mujoco.mj_setState(m, d, after, spec)
        full += t_full
        bare += t_bare
        ratios.append(t_full / t_bare)
    return full / (n_ctrl * nsub), bare / (n_ctrl * nsub), ratios


def _time_python_loop(sim: WristSim, refs: np.ndarray, control_dt: float, seconds: float) -> float:
    """The naive path: one ``mj_step`` per substep, NumPy springs into ``qfrc_applied`` (callbacks removed;
    the motor low-pass then runs on MuJoCo's filter via ctrl, i.e. without the speed limit: cheaper, if anything)."""
    backend = native.backend()
    native.uninstall()
    try:
        sim.reset(lam=0.5 * lambda_range(np.zeros(2), sim.params)[1])
        m, d = sim.model, sim.data
        q1, mot = sim._qadr_q1, sim._qadr_motor[:3]
        v1, vm = sim.model.jnt_dofadr[[sim.model.jnt_qposadr.tolist().index(a) for a in q1]], sim._vadr_motor[:3]
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
    finally:
        native.install(backend or "auto")
    return wall / (n_ctrl * nsub)


def speed(preset: str, seconds: float, rounds: int, control_dt: float, with_python: bool) -> dict:
    sim = WristSim(preset)
    refs = _reference_schedule(sim, 64)
    res: dict[str, list[float]] = {"bare": [], "full_c": [], "ratio": [], "python_loop": [],
                                   "python_callbacks": []}
    for _ in range(rounds):  # interleaved, so that load from other processes hits all alike; best of rounds
        native.install("c")
        full, bare, ratios = _time_paired(sim, refs, control_dt, seconds)
        res["full_c"].append(full)
        res["bare"].append(bare)
        res["ratio"] += ratios
        if with_python:
            res["python_loop"].append(_time_python_loop(sim, refs, control_dt / 5, seconds / 5))
            native.install("python")
            res["python_callbacks"].append(_time_full(sim, refs, control_dt, seconds / 5))
            native.install("c")
    out = {k: min(v) for k, v in res.items() if v}
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


SEEDS = (0, 1, 2)  # random-target sequences of the closure sweep


def closure_under_random_references(params, posture_rate: float | None, seconds: float = 10.0,
                                    seed: int = 1) -> tuple[float, float]:
    """Worst loop-closure error and fastest motor (rad/s) over random posture targets (new one every 0.5 s)
    at the largest preload, gravity on. ``posture_rate`` (rad/s) limits how fast the commanded posture
    moves; None: jumps. The closure is checked after every physics substep, motor speeds at every control
    period."""
    sim = WristSim(params)
    substeps = int(round(0.02 / sim.timestep))
    rng = np.random.default_rng(seed)
    u = np.zeros(2)
    sim.reset(u=u, lam=lambda_range(u, params)[1])
    worst, fastest, target, ps_target, ps = 0.0, 0.0, u, 0.0, 0.0
    for k in range(int(seconds / 0.02)):
        if k % 25 == 0:
            target, ps_target = rng.uniform(sim.kin.u_min, sim.kin.u_max), rng.uniform(-2.0, 2.0)
        if posture_rate is None:
            u, ps = target, ps_target
        else:
            step = target - u
            u = u + step * min(1.0, posture_rate * 0.02 / max(float(np.linalg.norm(step)), 1e-12))
            ps += float(np.clip(ps_target - ps, -posture_rate * 0.02, posture_rate * 0.02))
        sim.set_motor_references(np.append(motor_references(u, lambda_range(u, params)[1], params), ps))
        for _ in range(substeps):
            sim.step(sim.timestep)
            worst = max(worst, sim.loop_closure_error())
        fastest = max(fastest, float(np.abs(sim.motor_velocities()).max()))
    return worst, fastest


def _worst_over_seeds(params, posture_rate: float | None) -> tuple[float, float]:
    """closure_under_random_references, worst of SEEDS (seed 0: the same targets as tests/test_sim.py)."""
    runs = [closure_under_random_references(params, posture_rate, seed=seed) for seed in SEEDS]
    return max(r[0] for r in runs), max(r[1] for r in runs)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="vswrist bench-sim", description=__doc__)
    parser.add_argument("--params", default=None,
                        help=f"preset ({', '.join(PRESETS)}) or YAML; default: paper and paper_knm")
    parser.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per timing (default 4)")
    parser.add_argument("--rounds", type=int, default=5, help="interleaved timing rounds, best taken (default 3)")
    parser.add_argument("--control-dt", type=float, default=0.02, help="control period of step() calls, s")
    parser.add_argument("--no-python", action="store_true", help="skip the slow Python reference paths")
    parser.add_argument("--sweep", action="store_true", help="also sweep the timestep: accuracy against speed")
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
        print(f"  full, C callbacks (default)          {r['full_c'] * 1e6:8.2f} us   {1 / r['full_c']:10.0f} substeps/s   "
              f"ratio {r['ratio']:.3f} (median of paired windows; quartiles {r['ratio_iqr'][0]:.3f}-"
              f"{r['ratio_iqr'][1]:.3f})")
        rows = [("full, Python callbacks (fallback)", "python_callbacks"),
                ("Python loop, mj_step per substep", "python_loop")]
        for label, key in rows:
            if key in r:
                print(f"  {label:<36} {r[key] * 1e6:8.2f} us   {1 / r[key]:10.0f} substeps/s   "
                      f"ratio {r[key] / r['bare']:.3f}")
        print(f"  real-time factor (default path)      {dt / r['full_c']:.0f}x\n")
    if args.solvers:
        print("full substep (C callbacks) under other MuJoCo settings, same motion; best of rounds, "
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
        print("timestep sweep (constraint time constant = 2 substeps): stiffness error vs analytic (max over 3 cases),")
        print("paper-formula error, worst loop closure in 10 s of random posture references at the largest preload")
        print(f"(worst of seeds {', '.join(map(str, SEEDS))}; commanded posture moving at <= 3 rad/s; "
              "in brackets: jumping), speed")
        for preset in presets:
            base = load_params(preset)
            for dt in (0.00025, 0.0005, 0.001, 0.002):
                p = base.replace(simulation={"timestep": dt, "constraint_timeconst": 2 * dt})
                errs = [stiffness_error(p, u, f) for u, f in (((0.0, 0.0), 0.9), ((0.5, 0.4), -0.8), ((-0.6, -0.5), 0.3))]
                closure, speed_rate = _worst_over_seeds(p, 3.0)
                closure_jumps, speed_jumps = _worst_over_seeds(p, None)
                sim = WristSim(p)
                per = _time_full(sim, _reference_schedule(sim, 64), 0.02, 2.0)
                print(f"  [{preset}] dt {dt * 1e3:5.2f} ms  stiffness err {max(e for e, _ in errs):6.2%}  "
                      f"paper formula {min(e for _, e in errs):5.1%}-{max(e for _, e in errs):5.1%}  "
                      f"closure {closure:.1e} (jumps {closure_jumps:.1e})  fastest motor {speed_rate:4.1f} "
                      f"({speed_jumps:4.1f}) rad/s  {1 / per:7.0f} substeps/s  RTF {dt / per:4.0f}x")
    return 0
