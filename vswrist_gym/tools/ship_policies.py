"""Train, evaluate and package the shipped policies (``vswrist_gym/pretrained/<Task>_<track>/``) with their cards.

    python -m vswrist_gym.tools.ship_policies                      # everything: train, ship, evaluate, cards, README
    python -m vswrist_gym.tools.ship_policies --tasks Polish:full --timesteps 2000 --work /tmp/ship --dest /tmp/pre

Per task and track: ``vswrist train --task T --algo ppo --seed 0 --track TRACK`` with the packaged entry (its
budget unless ``--timesteps``), at most ``--jobs`` trainings at a time (subprocesses; runs already finished in
``--work`` are reused); the run directory trimmed to what ``runs.TrainedAgent`` loads (config.yaml, run.json,
model.zip, vecnormalize.npz) is copied to ``--dest``; the copy is evaluated (``pretrained:T:TRACK``, the protocol
of ``vswrist evaluate``) together with ``analytic:S`` for the fixed stiffness commands S on the same seeds and
episodes; ``card.json`` and ``CARD.md`` record the training command, commit, budget, the return and success with
95 % intervals over the evaluation seeds against the best constant, every episode's return (which the replay test
compares), and the replay's sensitivity to a perturbation of the policy's actions (what bounds the comparison on
another CPU). ``--readme`` rewrites the table between the README's ``pretrained-table`` markers from the cards.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import logging
import math
import os
import platform
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from vswrist_gym import pretrained

logger = logging.getLogger(__name__)

# LoadHold (both tracks) and Impact's stiffness track are not shipped: their policies lost to the best constant
# stiffness on the held-out episodes (`vswrist gate --shipped`), which tests/test_shipped_heldout.py refuses.
# Throw's and Hammer's (Hammer-v1's) tracks ship the median training seed of their leaderboard cells (`vswrist
# benchmark`), shipped with `--stage ship` from those runs; a plain rerun of this tool trains seed 0 instead.
SHIP = (("Polish", "full"), ("Impact", "full"), ("Insertion", "full"), ("Drill", "full"), ("Hammer", "stiffness"),
        ("Polish", "stiffness"), ("Insertion", "stiffness"), ("Drill", "stiffness"), ("Throw", "stiffness"),
        ("Throw", "full"), ("Hammer", "full"))
STIFFNESS = (-1.0, -0.5, 0.0, 0.5, 1.0)
EVAL_SEEDS = (0, 1, 2, 3, 4)
EVAL_EPISODES = 4
# relative size of the perturbation of the policy's actions that stands in for another CPU's rounding: torch's
# float32 kernels differ between CPUs by about one float32 ulp (1.2e-7 relative); 1e-5 is about 100 ulp
PERTURBATION = 1e-5
# cross-machine tolerance of a replayed episode's return: this many times the largest return change the
# perturbation caused, plus a floor for episodes the perturbation left unchanged
SPREAD_MARGIN = 10.0
TOLERANCE_FLOOR = 1e-4  # relative to the episode's |return|
README_MARKERS = ("<!-- pretrained-table:start -->", "<!-- pretrained-table:end -->")
REPO = Path(__file__).resolve().parents[2]


def cpu_id() -> str:
    """The CPU as far as floating-point results depend on it: a hypervisor may show only "AMD EPYC" for CPUs of
    different generations, whose SIMD extensions (AVX-512 or not) pick different code paths in numpy, torch and
    MuJoCo, so the family, model and SIMD flags are part of it."""
    fields = {}
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if not line.strip():
                    break  # the first processor's block describes them all
                key, _, value = line.partition(":")
                fields[key.strip()] = value.strip()
    except OSError:
        pass
    name = fields.get("model name") or platform.processor() or "unknown CPU"
    simd = sorted(f for f in fields.get("flags", "").split() if f.startswith(("avx", "fma", "amx")))
    return f"{name} (family {fields.get('cpu family', '?')}, model {fields.get('model', '?')}; {' '.join(simd)})"


def machine() -> str:
    """Where the card's returns are exact (MuJoCo's and torch's floats differ between CPUs and versions)."""
    import mujoco
    import torch

    return (f"mujoco {mujoco.__version__}, torch {torch.__version__}, numpy {np.__version__}, {platform.machine()}, "
            f"{cpu_id()}")


def git_commit() -> dict:
    def git(*args):
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True).stdout.strip()

    try:
        return {"commit": git("rev-parse", "HEAD") or "unknown",
                "dirty": bool(git("status", "--porcelain", "--untracked-files=no"))}
    except OSError:
        return {"commit": "unknown", "dirty": None}


def parse_item(text: str) -> tuple[str, str]:
    from vswrist_gym import task_name
    from vswrist_gym.agents.hparams import TRACKS

    task, _, track = text.partition(":")
    if track not in TRACKS:
        raise argparse.ArgumentTypeError(f"{text}: write TASK:TRACK with TRACK one of {', '.join(TRACKS)}")
    return task_name(task), track


# ----------------------------------------------------------------------------------------------------- training


def train_command(task: str, track: str, out: Path, timesteps: int | None) -> list[str]:
    args = ["train", "--task", task, "--algo", "ppo", "--seed", "0", "--track", track, "--out", str(out),
            "--no-progress"]
    return args + (["--timesteps", str(timesteps)] if timesteps else [])


def train_all(items, work: Path, timesteps: int | None, jobs: int, log=None) -> None:
    """Train what is missing, `jobs` subprocesses at a time; a run with a final model.zip is kept as it is."""
    log = log or logger.info
    queue = []
    for task, track in items:
        run = work / "runs" / pretrained.folder_name(task, track)
        if (run / "model.zip").is_file():
            log(f"{run}: trained already, kept")
            continue
        if run.exists():
            shutil.rmtree(run)  # an unfinished run of an earlier attempt: start it again
        queue.append((run, train_command(task, track, run, timesteps)))
    running: list[tuple[Path, subprocess.Popen, float]] = []
    failed = []
    while queue or running:
        while queue and len(running) < jobs:
            run, args = queue.pop(0)
            run.parent.mkdir(parents=True, exist_ok=True)
            logf = open(run.parent / f"{run.name}.log", "w")  # noqa: SIM115 - closed with the process
            log(f"training: vswrist {shlex.join(args)}")
            (run.parent / f"{run.name}.git.json").write_text(json.dumps(git_commit()))
            proc = subprocess.Popen([sys.executable, "-m", "vswrist_gym.cli", *args], stdout=logf,
                                    stderr=subprocess.STDOUT)
            running.append((run, proc, time.monotonic()))
        time.sleep(2)
        for entry in list(running):
            run, proc, start = entry
            if proc.poll() is not None:
                running.remove(entry)
                log(f"{run.name}: exit {proc.returncode} after {time.monotonic() - start:.0f} s")
                if proc.returncode != 0:
                    failed.append(run.name)
    if failed:
        raise SystemExit(f"ship_policies: training failed for {', '.join(failed)} (logs in {work / 'runs'})")


# ----------------------------------------------------------------------------------------------------- shipping


def ship_run(run: Path, dest: Path) -> None:
    """Copy the trimmed run directory (nothing but what TrainedAgent loads) to `dest`, replacing it."""
    if dest.exists():
        shutil.rmtree(dest)
    dest.mkdir(parents=True)
    for name in pretrained.RUN_FILES:
        if (run / name).is_file():
            shutil.copyfile(run / name, dest / name)  # package data: readable by all, not the run's 0600
            os.chmod(dest / name, 0o644)


class PerturbedAgent:
    """The policy with each action multiplied by (1 + PERTURBATION * r), r uniform in [-1, 1] (seeded): how much
    a replay's return moves when the policy's floats round differently, as they do on another CPU."""

    def __init__(self, agent, seed: int = 0):
        self.agent, self.rng = agent, np.random.default_rng(seed)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        action, state = self.agent.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        action = np.asarray(action)
        return action * (1.0 + PERTURBATION * self.rng.uniform(-1.0, 1.0, size=action.shape)), state


def evaluate_item(task: str, track: str, folder: Path, work: Path, seeds, episodes: int, stiffness) -> dict:
    """Evaluate the shipped copy and the fixed-stiffness baselines on the same episodes; returns the card's
    `evaluation` and `replay` sections."""
    from vswrist_gym.agents import evaluate as ev
    from vswrist_gym.agents.compare import against_baseline, best_baseline
    from vswrist_gym.agents.protocol import evaluate
    from vswrist_gym.agents.trained import TrainedAgent

    name = pretrained.folder_name(task, track)
    agent_text = f"pretrained:{task}:{track}" if folder.parent == pretrained.ROOT else str(folder)
    out_root = work / "eval" / name
    rows, docs = {}, {}
    for label, text in [("policy", agent_text)] + [(f"analytic:{s:+.2f}", f"analytic:{s}") for s in stiffness]:
        argv = ["--task", task, "--agent", text, "--seeds", *map(str, seeds), "--episodes", str(episodes),
                "--out", str(out_root / label.replace(":", "_"))]
        doc = ev.run(task, text, episodes, list(seeds), out_root / label.replace(":", "_"), argv=argv)
        docs[label] = doc
        rows[label] = doc["summary"]
    baselines = [k for k in rows if k != "policy"]
    best = best_baseline(rows, baselines)
    diff, verdict = against_baseline(rows, "policy", best)
    with open(out_root / "policy" / "metrics.json") as fh:
        episodes_doc = json.load(fh)["episodes"]

    def brief(summary):
        return {k: {m: summary[k][m] for m in ("mean", "low", "high", "per_seed")} for k in ("return", "success")}

    best_eps = json.loads((out_root / best.replace(":", "_") / "metrics.json").read_text())["episodes"]
    evaluation = {
        "seeds": list(seeds), "episodes_per_seed": episodes,
        "reset_seed": "1,000,000 + 1000 * seed + episode (vswrist evaluate's protocol)",
        "interval": "95 % Student-t over the evaluation seeds (per-seed means of their episodes) of ONE training "
                    "seed: it covers the task's randomisation, not training variability",
        "command": docs["policy"]["command"].replace(str(folder), agent_text),
        "policy": brief(rows["policy"]),
        "best_constant": {"agent": best, "stiffness": float(best.split(":")[1]), **brief(rows[best])},
        "constants": {k: brief(rows[k]) for k in baselines},
        "difference_vs_best_constant": {"return": {k: diff[k] for k in ("mean", "low", "high")},
                                        "verdict": verdict},
        "episodes": [{"seed": e["seed"], "episode": e["episode"], "return": e["return"], "success": e["success"]}
                     for e in episodes_doc],
        "best_constant_episodes": [{"seed": e["seed"], "episode": e["episode"], "return": e["return"]}
                                   for e in best_eps],
    }
    # sensitivity of the replay to rounding: the first seed's episodes with perturbed actions
    agent = TrainedAgent(folder)
    env_id = agent.env_id
    perturbed, _ = evaluate(env_id, lambda env: (agent.check_env(env), PerturbedAgent(agent))[1], [seeds[0]],
                            episodes, env_kwargs=dict(agent.cfg.env_kwargs))
    change = [abs(p["return"] - e["return"]) for p, e in zip(perturbed, episodes_doc)]
    replay = {
        "machine": machine(), "action_perturbation": PERTURBATION, "episodes_perturbed": len(change),
        "max_return_change": max(change), "relative_max_return_change":
            max(c / max(abs(e["return"]), 1e-12) for c, e in zip(change, episodes_doc)),
        "cross_machine_tolerance": {"margin": SPREAD_MARGIN, "relative_floor": TOLERANCE_FLOOR},
    }
    return {"evaluation": evaluation, "replay": replay}


def file_table(folder: Path) -> dict:
    return {p.name: {"bytes": p.stat().st_size, "sha256": hashlib.sha256(p.read_bytes()).hexdigest()}
            for p in sorted(folder.iterdir()) if p.name in pretrained.RUN_FILES}


def write_card(task: str, track: str, run: Path, folder: Path, result: dict) -> dict:
    from vswrist_gym.agents.fileio import atomic_write_text
    from vswrist_gym.agents.run_config import read_config

    cfg, seed = read_config(run)
    run_doc = json.loads((run / "run.json").read_text())
    git_file = run.parent / f"{run.name}.git.json"  # the code the run was trained with, saved at its start
    git = json.loads(git_file.read_text()) if git_file.is_file() else {**git_commit(), "note": "at shipping time"}
    commands = run_doc.get("commands") or []
    card = {
        "task": task, "env_id": cfg.env_id, "track": track, "algo": cfg.algo, "training_seed": seed,
        "budget_steps": int(cfg.n_timesteps), "steps_trained": run_doc.get("num_timesteps"),
        "training_time_s": run_doc.get("train_seconds"),
        "training_command": commands[0] if commands else None,
        "hyperparameters": f"the vswrist_gym/configs/ppo.yaml entry {cfg.env_id}, --track {track}",
        "env_kwargs": cfg.env_kwargs, "git": git,
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "host": {"machine": machine(), "cpu_count": os.cpu_count(), "load_average_1min": os.getloadavg()[0],
                 "note": "dev machine shared with other sessions (contended)"},
        "versions": run_doc.get("versions"),
        **{k: v for k, v in result.items() if k in ("evaluation", "replay")},
        "regenerate": "python -m vswrist_gym.tools.ship_policies",
        "files": file_table(folder),
    }
    from vswrist_gym.agents.protocol import json_safe

    atomic_write_text(folder / pretrained.CARD_FILE, json.dumps(json_safe(card), indent=2) + "\n")
    atomic_write_text(folder / "CARD.md", card_markdown(card))
    for name in pretrained.CARD_FILES:
        os.chmod(folder / name, 0o644)
    return card


def _ci(d: dict, fmt: str = ".1f") -> str:
    if d.get("low") is None or d["low"] != d["low"]:
        return f"{d['mean']:{fmt}}"
    return f"{d['mean']:{fmt}} [{d['low']:{fmt}}, {d['high']:{fmt}}]"


def card_markdown(card: dict) -> str:
    ev, rp = card["evaluation"], card["replay"]
    best = ev["best_constant"]
    lines = [
        f"# {card['algo'].upper()} on {card['env_id']}, {card['track']} track",
        "",
        f"`--agent pretrained:{card['task']}:{card['track']}` in `vswrist evaluate`, `vswrist video`, `vswrist view`.",
        "",
        *([card["env_id_note"], ""] if card.get("env_id_note") else []),
        "## Training",
        "",
        f"- command: `{card['training_command']}`",
        f"- budget: {card['budget_steps']:,} environment steps, training seed {card['training_seed']} (one seed)",
        f"- hyperparameters: {card['hyperparameters']}; env_kwargs `{json.dumps(card['env_kwargs'])}`",
        f"- commit: {card['git']['commit']}" + (" (with uncommitted changes)" if card['git'].get('dirty') else ""),
        f"- date: {card['date']}; machine: {card['host']['machine']}, {card['host']['cpu_count']} cores, "
        f"{card['host']['note']}" + (f"; training time {card['training_time_s']:.0f} s"
                                     if isinstance(card.get('training_time_s'), (int, float)) else ""),
        "",
        "## Evaluation",
        "",
        f"{len(ev['seeds'])} evaluation seeds ({' '.join(map(str, ev['seeds']))}) x {ev['episodes_per_seed']} "
        f"episodes, reset seed {ev['reset_seed']}; means with the {ev['interval']}.",
        "",
        "| agent | return | success |",
        "|---|---|---|",
        f"| this policy | {_ci(ev['policy']['return'])} | {_ci(ev['policy']['success'], '.2f')} |",
    ]
    for label, row in ev["constants"].items():
        mark = " (best constant)" if label == best["agent"] else ""
        lines.append(f"| {label}{mark} | {_ci(row['return'])} | {_ci(row['success'], '.2f')} |")
    d = ev["difference_vs_best_constant"]
    lines += [
        "",
        f"Paired difference in return against {best['agent']} (same episodes): {_ci(d['return'])}; the 95 % "
        f"intervals of the return: {d['verdict']}.",
        "",
        f"Command: `{ev['command']}` (and the same with `--agent analytic:S`).",
        "",
        "## Replay",
        "",
        f"`card.json` holds every episode's return. On the machine above ({rp['machine']}) a replay gives them to "
        f"1e-6. Multiplying the policy's actions by 1 + {rp['action_perturbation']:g} r (r uniform in [-1, 1]), "
        f"a stand-in for another CPU's rounding, changed the returns of seed {ev['seeds'][0]}'s episodes by at most "
        f"{rp['max_return_change']:.3g} ({rp['relative_max_return_change']:.2g} relative); elsewhere the test "
        f"allows {rp['cross_machine_tolerance']['margin']:g} times that, or {rp['cross_machine_tolerance']['relative_floor']:g} "
        "of the return if larger (tests/test_pretrained.py).",
        "",
        "Files: " + ", ".join(f"`{k}` ({v['bytes'] / 1024:.0f} KiB)" for k, v in card["files"].items()) + ".",
        "",
    ]
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------------- README


def cards_table(root: Path | None = None) -> str:
    """The README's table of shipped policies, from their card.json files."""
    lines = ["| `--agent` | budget | return, policy | return, best constant | paired difference | success, policy "
             "| success, best constant |", "|---|---|---|---|---|---|---|"]
    for (task, track), folder in pretrained.shipped(root).items():
        card = json.loads((folder / pretrained.CARD_FILE).read_text())
        ev = card["evaluation"]
        best = ev["best_constant"]
        lines.append(f"| `pretrained:{task}:{track}` | {card['budget_steps']:,} | {_ci(ev['policy']['return'])} | "
                     f"{_ci(best['return'])} ({best['agent']}) | {_ci(ev['difference_vs_best_constant']['return'])} "
                     f"| {_ci(ev['policy']['success'], '.2f')} | {_ci(best['success'], '.2f')} |")
    return "\n".join(lines)


def update_readme(path: Path, root: Path | None = None) -> None:
    text = path.read_text()
    start, end = README_MARKERS
    if start not in text or end not in text:
        raise SystemExit(f"ship_policies: {path} has no {start} ... {end} markers")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    path.write_text(f"{head}{start}\n{cards_table(root)}\n{end}{tail}")


# ----------------------------------------------------------------------------------------------------- main


def _evaluate_job(args):
    task, track, run, folder, work, seeds, episodes, stiffness = args
    from vswrist_gym.agents.procs import limit_threads

    limit_threads(1)
    ship_run(run, folder)
    result = evaluate_item(task, track, folder, work, seeds, episodes, stiffness)
    write_card(task, track, run, folder, result)
    return f"{folder}: {json.dumps(result['evaluation']['difference_vs_best_constant'])}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m vswrist_gym.tools.ship_policies", description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", nargs="+", type=parse_item, default=list(SHIP),
                    help="TASK:TRACK items (default: " + " ".join(f"{t}:{k}" for t, k in SHIP) + ")")
    ap.add_argument("--timesteps", type=int, help="training steps (default: the entry's n_timesteps)")
    ap.add_argument("--seeds", type=int, nargs="+", default=list(EVAL_SEEDS), help="evaluation seeds")
    ap.add_argument("--episodes", type=int, default=EVAL_EPISODES, help="evaluation episodes per seed")
    ap.add_argument("--stiffness", type=float, nargs="+", default=list(STIFFNESS), help="fixed stiffness commands")
    ap.add_argument("--jobs", type=int, default=2, help="trainings / evaluations at a time (default 2)")
    ap.add_argument("--work", default="runs/ship", help="training runs and evaluation outputs (default runs/ship)")
    ap.add_argument("--dest", default=str(pretrained.ROOT), help="where the policies ship (default: the package)")
    ap.add_argument("--stage", choices=("train", "ship", "all"), default="all",
                    help="train only, ship (copy, evaluate, cards) trained runs only, or both (default)")
    ap.add_argument("--readme", nargs="?", const=str(REPO / "README.md"),
                    help="rewrite the README's table of shipped policies (default README.md)")
    args = ap.parse_args(argv)
    work, dest = Path(args.work), Path(args.dest).resolve()
    if args.stage in ("train", "all"):
        train_all(args.tasks, work, args.timesteps, args.jobs)
    if args.stage in ("ship", "all"):
        from concurrent.futures import ProcessPoolExecutor

        jobs = [(t, k, work / "runs" / pretrained.folder_name(t, k), dest / pretrained.folder_name(t, k), work,
                 args.seeds, args.episodes, args.stiffness) for t, k in args.tasks]
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            for line in pool.map(_evaluate_job, jobs):
                print(line)
    if args.readme:
        update_readme(Path(args.readme), dest)
        logger.info(f"{args.readme}: table of shipped policies rewritten")
    return 0


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
