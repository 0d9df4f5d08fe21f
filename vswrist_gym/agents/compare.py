"""`vswrist compare`: train (or load) PPO and SAC (`--algos` adds ppo_lstm, recurrent PPO), evaluate them and the
analytic baseline at fixed stiffness levels under the same seeds, print a table of means with 95 % confidence
intervals over seeds, and write plots.

Seeds: the learned agents are trained once per seed (training seed s) and evaluated on the evaluation episodes of
seed s; the analytic baseline is evaluated on the same episodes. The confidence interval is over seeds (for the
learned agents it therefore covers training variability as well as task randomisation).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import shlex
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from vswrist_gym.agents.baseline import DEFAULT_STIFFNESS_LEVELS
from vswrist_gym.agents.hparams import ALGO_NAMES, TRACKS, ConfigError, load_config, track_of
from vswrist_gym.agents.protocol import (METRICS, check_eval_seeds, evaluate, json_safe, summarise,
                                         write_metrics, write_partial)
from vswrist_gym.agents.fileio import RunDirError, check_new_out, check_writable, folder_bytes
from vswrist_gym.agents.procs import steps_done, versions
from vswrist_gym.agents.progress import set_enabled as set_progress
from vswrist_gym.agents.run_config import check_seed, read_config
from vswrist_gym.agents.trained import TrainedAgent

logger = logging.getLogger(__name__)

# what a compare output folder holds: a folder with anything else is refused as --out
COMPARE_OUTPUT_NAMES = ("table.md", "summary.json", "learning_curves.png", "traces.png", "eval", "runs")

# the algorithms `vswrist compare` trains unless --algos says otherwise (the README's main job: PPO and SAC)
DEFAULT_ALGOS = ("ppo", "sac")
TABLE_METRICS = ("return", "success", "rms_posture_error", "peak_contact_force", "rms_contact_force",
                 "elastic_energy", "stiffness_used")


def _short(env_id: str) -> str:
    return env_id.split("/")[-1].rsplit("-v", 1)[0]


def plan_run(env_id: str, algo: str, seed: int, run_dir: Path, timesteps: int | None, config, retrain: bool,
             track: str | None = None):
    """What a (algo, seed) run needs: ('load' | 'resume' | 'train', steps wanted)."""
    if retrain and (run_dir / "config.yaml").exists():  # only a run is deleted; any other folder is refused later
        shutil.rmtree(run_dir)
    wanted = timesteps or load_config(algo, env_id, config).n_timesteps
    if (run_dir / "config.yaml").exists():
        cfg, old_seed = read_config(run_dir)
        if cfg.env_id != env_id or cfg.algo != algo or old_seed != seed:
            raise RunDirError(f"{run_dir} holds {cfg.algo} seed {old_seed} on {cfg.env_id}; use --retrain or --out")
        if track is not None and track_of(cfg.env_kwargs) != track:
            raise RunDirError(f"{run_dir} is a {track_of(cfg.env_kwargs)}-track run, not {track}; use --retrain or "
                              "--out")
        run_json = run_dir / "run.json"
        done = json.loads(run_json.read_text()).get("num_timesteps", 0) if run_json.exists() else 0
        if (run_dir / "model.zip").exists() and done >= wanted:
            return "load", wanted
        return "resume", wanted
    return "train", wanted


def run_trainings(env_id: str, plans: list[dict], jobs: int, n_envs, progress: bool, log,
                  track: str | None = None) -> None:
    """Run the planned trainings: in this process (jobs = 1) or as up to `jobs` concurrent `vswrist train`
    subprocesses (each logs to <run_dir>.log)."""
    import subprocess

    from vswrist_gym.agents.train import TrainingError, train

    todo = [p for p in plans if p["action"] != "load"]
    if jobs <= 1:
        for p in todo:
            log(f"[{p['algo']} seed {p['seed']}] {p['action']} to {p['wanted']} steps -> {p['run_dir']}")
            start = time.time()
            try:
                train(env_id, p["algo"], p["run_dir"], config=p["config"], timesteps=p["wanted"], seed=p["seed"],
                      n_envs=n_envs, resume=p["action"] == "resume", progress=progress, log=log, track=track)
                p["what"] = f"{p['action']} {p['wanted']} steps in {time.time() - start:.0f} s"
            except TrainingError as exc:
                p["failed"] = str(exc)
                p["what"] = f"FAILED: {exc}"
                log(f"[{p['algo']} seed {p['seed']}] {p['what']}")
        return
    running: list[tuple[dict, subprocess.Popen, float, object]] = []
    queue = list(todo)
    failed = []
    last_report = time.time()
    while queue or running:
        if running and time.time() - last_report > 30:
            last_report = time.time()
            log("  progress: " + ", ".join(f"{p['algo']} seed {p['seed']} {steps_done(p['run_dir']):,}/{p['wanted']:,}"
                                           for p, *_ in running) + f"; {len(queue)} queued")
        while queue and len(running) < jobs:
            p = queue.pop(0)
            cmd = [sys.executable, "-m", "vswrist_gym.cli", "train", "--task", env_id, "--algo", p["algo"],
                   "--seed", str(p["seed"]), "--timesteps", str(p["wanted"]), "--out", str(p["run_dir"]),
                   "--no-progress"]
            if p["config"]:
                cmd += ["--config", str(p["config"])]
            if n_envs:
                cmd += ["--n-envs", str(n_envs)]
            if track:
                cmd += ["--track", track]
            if p["action"] == "resume":
                cmd.append("--resume")
            p["run_dir"].parent.mkdir(parents=True, exist_ok=True)
            fh = open(p["run_dir"].with_suffix(".log"), "w")
            # concurrent trainings share the cores: each batch gets its share of physics threads
            from vswrist_gym.envs.batch import THREADS_ENV, default_threads

            child_env = {**os.environ, THREADS_ENV: str(max(1, default_threads() // jobs))}
            log(f"[{p['algo']} seed {p['seed']}] {p['action']} to {p['wanted']} steps -> {p['run_dir']} (subprocess)")
            running.append((p, subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=child_env), time.time(),
                            fh))
        time.sleep(0.2)
        for item in list(running):
            p, proc, start, fh = item
            if proc.poll() is not None:
                fh.close()
                running.remove(item)
                if proc.returncode != 0:
                    tail = p["run_dir"].with_suffix(".log").read_text().strip().splitlines()[-1:]
                    p["failed"] = f"exit {proc.returncode}: " + " / ".join(tail)
                    p["what"] = f"FAILED ({p['failed']}); log: {p['run_dir'].with_suffix('.log')}"
                    log(f"[{p['algo']} seed {p['seed']}] {p['what']}")
                    if proc.returncode not in (1,):  # 1 = the environment failed; anything else is a usage error
                        failed.append(f"{p['algo']} seed {p['seed']}: {p['failed']}")
                else:
                    p["what"] = f"{p['action']} {p['wanted']} steps in {time.time() - start:.0f} s"
                    log(f"[{p['algo']} seed {p['seed']}] {p['what']}")
    if failed:
        raise TrainingError("training failed: " + "; ".join(failed))


def _num(x: float, name: str) -> str:
    if name == "success" or 1 <= abs(x) < 100:
        return f"{x:.2f}"
    if abs(x) >= 100:
        return f"{x:.0f}"
    return f"{x:.3g}"


def _isnan(x) -> bool:
    return x is None or (isinstance(x, float) and math.isnan(x))


def _cell(s: dict, name: str) -> str:
    if _isnan(s["mean"]):
        return "n/a"
    if _isnan(s["low"]):
        return _num(s["mean"], name)
    return f"{_num(s['mean'], name)} [{_num(s['low'], name)}, {_num(s['high'], name)}]"


def table_markdown(rows: list[tuple[str, dict]], metrics=TABLE_METRICS) -> str:
    """The summary table; a task's own metric (``TASK_METRICS``, e.g. Hammer's impact speed) joins the columns
    where some row reports it."""
    from vswrist_gym.agents.protocol import TASK_METRICS

    metrics = tuple(metrics) + tuple(m for m in TASK_METRICS if m not in metrics and any(
        m in summary and not _isnan(summary[m]["mean"]) for _, summary in rows))
    head = "| agent | " + " | ".join(f"{m}" + (f" ({METRICS[m][0]})" if METRICS[m][0] else "") for m in metrics) + " |"
    lines = [head, "|" + "---|" * (len(metrics) + 1)]
    for label, summary in rows:
        lines.append(f"| {label} | " + " | ".join(_cell(summary[m], m) for m in metrics) + " |")
    return "\n".join(lines)


def best_baseline(rows: dict[str, dict], baselines: list[str]) -> str | None:
    """The fixed-stiffness baseline with the highest mean return (None if none has one)."""
    valid = [b for b in baselines if not math.isnan(rows[b]["return"]["mean"])]
    return max(valid, key=lambda b: rows[b]["return"]["mean"]) if valid else None


def against_baseline(rows: dict[str, dict], name: str, best: str) -> tuple[dict, str]:
    """Agent ``name`` against baseline ``best``: the paired difference in return (same seeds, same episodes) with
    its CI, and the verdict of the 95 % CIs of the return over seeds: 'beats', 'worse', 'overlap' or 'no CI'."""
    from vswrist_gym.agents.protocol import mean_ci

    r, b = rows[name]["return"], rows[best]["return"]
    base_by_seed = dict(zip(b["seeds"], b["per_seed"]))
    diff = mean_ci([x - base_by_seed[s] for s, x in zip(r["seeds"], r["per_seed"]) if s in base_by_seed])
    if any(math.isnan(x) for x in (r["low"], r["high"], b["low"], b["high"])):
        return diff, "no CI"
    if r["low"] > b["high"]:
        return diff, "beats"
    if r["high"] < b["low"]:
        return diff, "worse"
    return diff, "overlap"


def verdicts(rows: dict[str, dict], learned: list[str], baselines: list[str]) -> dict:
    """Each learned agent against the best fixed-stiffness baseline (highest mean return): beats / worse / overlap
    by the 95 % CIs of the return over seeds, and the paired difference (same seeds, same episodes) with its CI."""
    best = best_baseline(rows, baselines)
    if best is None:
        return {}
    out = {"best_baseline": best}
    for name in learned:
        diff, kind = against_baseline(rows, name, best)
        paired = (f"; paired difference in return {diff['mean']:+.1f} [{diff['low']:+.1f}, {diff['high']:+.1f}]"
                  if not math.isnan(diff["low"]) else "")
        out[name] = {
            "no CI": "no CI (fewer than two seeds)",
            "beats": f"beats {best} (95 % CIs of the return do not overlap){paired}",
            "worse": f"worse than {best} (95 % CIs of the return do not overlap){paired}",
            "overlap": f"not distinguishable from {best} (95 % CIs of the return overlap){paired}",
        }[kind]
    return out


def plot_learning_curves(path: Path, runs: dict[str, list[Path]], baseline: tuple[str, float] | None, title: str):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for (algo, dirs), color in zip(runs.items(), ("tab:blue", "tab:orange", "tab:green")):
        curves = []
        for d in dirs:
            f = d / "eval" / "evaluations.npz"
            if f.is_file():
                with np.load(f) as ev:
                    curves.append((ev["timesteps"], ev["results"].mean(axis=1)))
                ax.plot(*curves[-1], color=color, alpha=0.25, lw=1)
        if curves:
            n = min(len(c[0]) for c in curves)
            if n:
                mean = np.mean([c[1][:n] for c in curves], axis=0)
                ax.plot(curves[0][0][:n], mean, color=color, lw=2,
                        label=f"{algo.upper()} (mean of {len(curves)} seeds)")
    if baseline is not None:
        ax.axhline(baseline[1], color="k", ls="--", lw=1, label=f"{baseline[0]} (protocol evaluation)")
    ax.set_xlabel("training steps")
    ax.set_ylabel("evaluation return")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no periodic evaluation yet", ha="center", transform=ax.transAxes)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def trace_signals(traces: dict[str, dict]) -> tuple:
    """The three panels of ``traces.png`` (trace key, axis label): posture error, the contact force, and the
    internal torque; on a task without contact (Throw), whose contact force is 0 throughout, the step reward in
    place of the force, so that the panel shows when the task pays."""
    shown = [tr for tr in traces.values() if tr is not None]
    touched = any(any(f != 0.0 for f in tr["contact_force"]) for tr in shown)
    rewards = all("reward" in tr for tr in shown)  # traces written before they held the reward keep the force
    middle = ("reward", "step reward") if rewards and not touched else ("contact_force", "contact force (N)")
    return (("posture_error", "posture error (rad)"), middle, ("lam", "internal torque lambda (N m)"))


def plot_traces(path: Path, traces: dict[str, dict], title: str, highlight: str | None = None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(6.4, 6.4), sharex=True)
    signals = trace_signals(traces)
    for label, tr in traces.items():
        if tr is None:
            continue
        faint = label.startswith("analytic") and label != highlight  # learned agents and the best baseline stand out
        for ax, (key, _) in zip(axes, signals):
            ax.plot(tr["time"], tr[key], lw=0.8 if faint else 1.6, alpha=0.45 if faint else 1.0,
                    ls="--" if faint else "-", label=label + (" (best fixed)" if label == highlight else ""))
    for ax, (_, ylabel) in zip(axes, signals):
        ax.set_ylabel(ylabel, fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].set_title(title, fontsize=9)
    axes[0].legend(fontsize=7, ncol=2)
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_outputs(out: Path, env_id: str, rows: dict, runs: dict, traces: dict, learned: list[str],
                  baselines: list[str], seeds: list[int], episodes: int, stiffness, budget: dict, training: dict,
                  t_train: float, t_total: float, load_start: float, command: str | None, trace_at,
                  track: str | None = None) -> dict:
    """Verdicts, table.md, summary.json, learning_curves.png and traces.png of one task's rows (per-agent
    `summarise` results): what `vswrist compare` writes, and `vswrist sweep` for each task of its grid."""
    verdict = verdicts(rows, learned, baselines)
    table = table_markdown(list(rows.items()))
    header = (f"{env_id}: means with 95 % confidence intervals over seeds {seeds} "
              f"({episodes} evaluation episodes per seed); training steps per seed: "
              + ", ".join(f"{a.upper()} {n}" for a, n in budget.items()))
    baseline_line = None
    if verdict:
        best = verdict["best_baseline"]
        baseline_line = (best, rows[best]["return"]["mean"])
    plot_learning_curves(out / "learning_curves.png", runs, baseline_line, f"{env_id}: periodic evaluation")
    plot_traces(out / "traces.png", traces, f"{env_id}: evaluation episode (seed {trace_at[0]}, episode 0)",
                highlight=verdict.get("best_baseline"))
    doc = {"task": env_id, "track": track, "seeds": seeds, "episodes_per_seed": episodes,
           "stiffness_levels": list(stiffness), "timesteps": budget, "training": training, "verdicts": verdict, "rows": rows,
           "seconds": {"training": round(t_train, 1), "total": round(t_total, 1)}, "versions": versions(),
           "load_average_1min": {"start": round(load_start, 2), "end": round(os.getloadavg()[0], 2)},
           "command": command, "traces": traces}
    (out / "summary.json").write_text(json.dumps(json_safe(doc), indent=2))
    md = [f"# {header}", "", table, ""]
    md += [f"- {k}: {v}" for k, v in verdict.items()]
    md += [f"- {name}: {what}" for name, what in training.items() if what.startswith("FAILED")]
    md += ["", f"Wall time {t_total:.0f} s (training {t_train:.0f} s) on {os.cpu_count()} cores, 1-min load average "
           f"{load_start:.1f} at start and {os.getloadavg()[0]:.1f} at end; "
           f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; versions: "
           + ", ".join(f"{k} {v}" for k, v in versions().items() if k != "platform")]
    if command is not None:
        md += ["", f"Command: `{command}`"]
    (out / "table.md").write_text("\n".join(md) + "\n")
    doc["table"], doc["header"], doc["out"] = table, header, out
    return doc


def compare(task: str, algos=DEFAULT_ALGOS, seeds=(0, 1, 2), episodes: int = 10, stiffness=DEFAULT_STIFFNESS_LEVELS,
            out: str | Path | None = None, timesteps: dict | None = None, configs: dict | None = None,
            n_envs: int | None = None, retrain: bool = False, analytic: bool = True, progress: bool = True,
            jobs: int = 1, runs_dir: str | Path | None = None, argv: list[str] | None = None, log=None,
            track: str | None = None) -> dict:
    from vswrist_gym.agents.evaluate import AgentSpec
    from vswrist_gym.agents.procs import limit_threads
    from vswrist_gym.agents.train import check_run_out, task_id

    log = log or logger.info
    seeds = [check_seed(s, "--seeds") for s in seeds]  # training seeds, and evaluation seeds below
    check_eval_seeds(seeds, episodes)
    env_id = task_id(task)
    if track is not None and track not in TRACKS:
        raise ConfigError(f"--track must be one of {', '.join(TRACKS)}, got {track!r}")
    out = Path(out) if out else Path("runs") / "compare" / (_short(env_id) + (f"_{track}" if track else ""))
    check_new_out(out, allowed=COMPARE_OUTPUT_NAMES,
                  what=f"a vswrist compare output folder ({', '.join(COMPARE_OUTPUT_NAMES)})")
    if runs_dir:
        check_writable(runs_dir, "--runs-dir")
    limit_threads(1)
    timesteps, configs = timesteps or {}, configs or {}
    t0 = time.time()
    load_start = os.getloadavg()[0]  # other work on the machine slows the wall time: record it

    runs: dict[str, list[Path]] = {algo: [] for algo in algos}
    plans = []
    for algo in algos:
        for s in seeds:
            run_dir = (Path(runs_dir) if runs_dir else out / "runs") / f"{algo}_seed{s}"
            action, wanted = plan_run(env_id, algo, s, run_dir, timesteps.get(algo), configs.get(algo), retrain,
                                      track)
            plans.append({"algo": algo, "seed": s, "run_dir": run_dir, "action": action, "wanted": wanted,
                          "config": configs.get(algo), "what": f"loaded ({wanted} steps)"})
            runs[algo].append(run_dir)
    for p in plans:  # every run directory checked before the first training starts
        if p["action"] == "train":
            check_run_out(p["run_dir"], resume=False)
        elif p["action"] == "resume":
            check_writable(p["run_dir"], "run directory")
    out.mkdir(parents=True, exist_ok=True)
    for p in plans:
        if p["action"] == "load":
            log(f"[{p['algo']} seed {p['seed']}] loaded {p['run_dir']} ({p['wanted']} steps)")
    run_trainings(env_id, plans, jobs, n_envs, progress, log, track)
    training = {f"{p['algo']}_seed{p['seed']}": p["what"] for p in plans}
    # a run whose environment failed is reported and left out, not silently dropped
    failed_runs = {p["run_dir"] for p in plans if p.get("failed")}
    runs = {a: [d for d in dirs if d not in failed_runs] for a, dirs in runs.items()}
    algos = [a for a in algos if runs[a]]
    t_train = time.time() - t0

    rows: dict[str, dict] = {}
    traces: dict[str, dict] = {}
    trace_at = (seeds[0], 0)
    env_kwargs_seen = set()
    for algo in algos:
        records = []
        head = {"task": env_id, "agent": algo.upper(), "seeds": seeds, "episodes_per_seed": episodes}
        (out / "eval" / algo).mkdir(parents=True, exist_ok=True)
        for run_dir in runs[algo]:
            agent = TrainedAgent(run_dir)
            s = agent.seed
            env_kwargs_seen.add(json.dumps(agent.cfg.env_kwargs, sort_keys=True))
            recs, tr = evaluate(env_id, lambda env, a=agent: (a.check_env(env), a)[1], [s], episodes,
                                env_kwargs=agent.cfg.env_kwargs, trace_episode=trace_at,
                                desc=f"{algo.upper()} seed {s}",
                                on_record=lambda r, done=list(records): write_partial(out / "eval" / algo, head,
                                                                                      done + r))
            records += recs
            if tr is not None:
                traces[algo.upper()] = tr
        rows[algo.upper()] = summarise(records)
        write_metrics(out / "eval" / algo, head, records, rows[algo.upper()])
        log(f"evaluated {algo.upper()}: return {rows[algo.upper()]['return']['mean']:.4g}")
    if len(env_kwargs_seen) > 1:
        logger.warning(f"the {' and '.join(a.upper() for a in algos)} runs use different env_kwargs; their rows "
                       "are not on the same environment")
    baselines = []
    if analytic:
        for k in stiffness:
            spec = AgentSpec(f"analytic:{k}")
            folder = out / "eval" / f"analytic_{k:+.2f}"
            head = {"task": env_id, "agent": spec.label, "seeds": seeds, "episodes_per_seed": episodes}
            folder.mkdir(parents=True, exist_ok=True)
            records, tr = evaluate(env_id, spec.make, seeds, episodes, trace_episode=trace_at, desc=spec.label,
                                   on_record=lambda r, f=folder, h=head: write_partial(f, h, r))
            rows[spec.label] = summarise(records)
            baselines.append(spec.label)
            traces[spec.label] = tr
            write_metrics(folder, head, records, rows[spec.label])
            log(f"evaluated {spec.label}: return {rows[spec.label]['return']['mean']:.4g}")
    t_total = time.time() - t0
    budget = {a: (timesteps.get(a) or load_config(a, env_id, configs.get(a)).n_timesteps) for a in algos}
    command = "vswrist compare " + shlex.join(argv) if argv is not None else None
    # the track the learned runs trained on (from their own configs, so loaded runs count as they are)
    run_track = "/".join(sorted({track_of(json.loads(k)) for k in env_kwargs_seen})) or None
    doc = write_outputs(out, env_id, rows, runs, traces, [a.upper() for a in algos], baselines, seeds, episodes,
                        stiffness, budget, training, t_train, t_total, load_start, command, trace_at, track=run_track)
    doc["footprint"] = {"run_bytes": {a.upper(): sum(folder_bytes(d) for d in runs[a]) for a in algos},
                        "runs_dir": str(Path(runs_dir) if runs_dir else out / "runs"), "out_bytes": folder_bytes(out)}
    return doc


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vswrist compare", description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("--task", required=True, help="task id (VSWrist/LoadHold-v0) or short name (LoadHold: its newest version)")
    p.add_argument("--algos", nargs="+", choices=ALGO_NAMES, default=list(DEFAULT_ALGOS),
                   help="algorithms to train (default ppo sac; ppo_lstm: sb3-contrib's RecurrentPPO)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2],
                   help="training and evaluation seeds (default 0 1 2)")
    p.add_argument("--episodes", type=int, default=10, help="evaluation episodes per seed (default 10)")
    p.add_argument("--stiffness", type=float, nargs="+", default=list(DEFAULT_STIFFNESS_LEVELS),
                   help="fixed stiffness commands of the analytic baseline, each in [-1, 1]")
    p.add_argument("--out", help="output directory (default runs/compare/<task>)")
    p.add_argument("--runs-dir", help="where the training runs live (default OUT/runs); keeps models out of OUT")
    p.add_argument("--ppo-timesteps", type=int, help="PPO training steps per seed (default: configs/ppo.yaml)")
    p.add_argument("--sac-timesteps", type=int, help="SAC training steps per seed (default: configs/sac.yaml)")
    p.add_argument("--ppo-config", help="PPO hyperparameter file (default configs/ppo.yaml)")
    p.add_argument("--sac-config", help="SAC hyperparameter file (default configs/sac.yaml)")
    p.add_argument("--ppo-lstm-timesteps", type=int,
                   help="PPO_LSTM training steps per seed (default: configs/ppo_lstm.yaml)")
    p.add_argument("--ppo-lstm-config", help="PPO_LSTM hyperparameter file (default configs/ppo_lstm.yaml)")
    p.add_argument("--n-envs", type=int, help="parallel environments per training run (overrides n_envs)")
    p.add_argument("--track", choices=TRACKS,
                   help="stiffness: the policies set only the stiffness; full: posture and stiffness (default: as "
                        "the config entries say); the default output folder gets the track as a suffix")
    p.add_argument("--jobs", type=int, default=2,
                   help="training runs at a time, as subprocesses (default 2: one per core of a 2-core machine)")
    p.add_argument("--retrain", action="store_true", help="delete and retrain existing runs in --out")
    p.add_argument("--no-analytic", action="store_true", help="skip the analytic baseline")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    if args.no_progress:
        set_progress(False)
    try:
        for k in args.stiffness:
            if not -1.0 <= k <= 1.0:
                raise ConfigError(f"--stiffness values must be in [-1, 1], got {k}")
        for name in ("episodes", "ppo_timesteps", "sac_timesteps", "ppo_lstm_timesteps", "n_envs", "jobs"):
            v = getattr(args, name)
            if v is not None and v <= 0:
                raise ConfigError(f"--{name.replace('_', '-')} must be a positive integer, got {v}")
        doc = compare(args.task, algos=args.algos, seeds=args.seeds, episodes=args.episodes, stiffness=args.stiffness,
                      out=args.out, timesteps={algo: getattr(args, f"{algo}_timesteps") for algo in ALGO_NAMES},
                      configs={algo: getattr(args, f"{algo}_config") for algo in ALGO_NAMES}, n_envs=args.n_envs,
                      retrain=args.retrain, analytic=not args.no_analytic, progress=not args.no_progress,
                      jobs=args.jobs, runs_dir=args.runs_dir, argv=argv, track=args.track)
    except (ConfigError, RunDirError, ValueError) as exc:
        print(f"vswrist compare: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # TrainingError: an environment or worker failed during training
        print(f"vswrist compare: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # the disk filled or a folder became unwritable during the job
        print(f"vswrist compare: error: {exc}", file=sys.stderr)
        return 1
    print()
    print(doc["header"])
    print(doc["table"])
    for k, v in doc["verdicts"].items():
        print(f"  {k}: {v}")
    for name, what in doc["training"].items():
        if what.startswith("FAILED"):
            print(f"  {name}: {what}")
    out = doc["out"]
    logger.info(f"wrote {out / 'table.md'}, plots {out / 'learning_curves.png'} and {out / 'traces.png'}, "
                f"per-episode metrics {out / 'eval'}/*/metrics.csv")
    fp = doc["footprint"]
    per_algo = ", ".join(f"{a} {n / 1e6:.1f} MB" for a, n in fp["run_bytes"].items())
    logger.info(f"disk: {fp['out_bytes'] / 1e6:.1f} MB in {out}; run directories in {fp['runs_dir']} ({per_algo})")
    return 0
