"""`vswrist evaluate`: any agent, trained or analytic, under one protocol; per-episode metrics to JSON and CSV.

Examples:
    vswrist evaluate --task LoadHold --agent runs/loadhold_ppo_0 --episodes 10 --seeds 0 1 2 --out eval/ppo
    vswrist evaluate --task Polish --agent logs/ppo/VSWrist-Polish-v1_1 --seeds 0 --out eval/zoo   # RL Zoo run
    vswrist evaluate --task LoadHold --agent analytic:0.5 --episodes 10 --seeds 0 1 2 --out eval/analytic_0.5

`--out` is checked before the first episode (writable, and either new, empty or an earlier evaluation's folder);
every finished episode is saved to OUT/episodes.partial.jsonl at once, so a crash or kill loses none of them.
"""

from __future__ import annotations

import argparse
import logging
import shlex
import sys
from pathlib import Path

from vswrist_gym.agents.hparams import ConfigError
from vswrist_gym.agents.protocol import (METRICS, PARTIAL_FILE, RATE_METRICS, TASK_METRICS, check_eval_seeds,
                                         evaluate, summarise, write_metrics, write_partial)
from vswrist_gym.agents.fileio import RunDirError, check_new_out, check_writable
from vswrist_gym.agents.procs import versions
from vswrist_gym.agents.trained import TrainedAgent

logger = logging.getLogger(__name__)

# what an evaluation output folder holds: a folder with anything else is refused as --out
EVAL_OUTPUT_NAMES = ("metrics.json", "metrics.csv", PARTIAL_FILE)


CHECKPOINT_CHOICES = ("newest", "final", "latest", "best")
CHECKPOINT_HELP = ("which model of a run directory: newest (default: the newest model run.json accounts for, "
                   "model.zip or a later checkpoint), final (model.zip, even when the run went on), latest "
                   "checkpoint, best periodic evaluation")


class AgentSpec:
    """An agent named on the command line: 'analytic', 'analytic:STIFFNESS' (in [-1, 1]), a run directory, an RL
    Zoo experiment folder, a model file inside either (see runs.TrainedAgent), or a policy shipped in the package,
    'pretrained:<Task>[:<track>]' (agents.shipped). `vswrist evaluate`, `video` and `view` all parse
    --agent here."""

    def __init__(self, text: str, checkpoint: str = "newest"):
        self.text = text
        self.trained: TrainedAgent | None = None
        self.stiffness: float | None = None
        self.pretrained: Path | None = None
        if text.startswith("pretrained:"):
            from vswrist_gym.agents import shipped

            self.kind = "trained"
            self.pretrained = shipped.resolve(text)
            if checkpoint not in ("final", "newest"):
                raise ConfigError(f"--checkpoint {checkpoint}: a shipped policy ({text}) has its final model only")
            self.trained = TrainedAgent(self.pretrained, checkpoint="final")
        elif text == "analytic" or text.startswith("analytic:"):
            self.kind = "analytic"
            if ":" in text:
                try:
                    self.stiffness = float(text.split(":", 1)[1])
                except ValueError:
                    raise ConfigError(f"--agent {text}: the stiffness after 'analytic:' must be a number in "
                                      f"[-1, 1]") from None
                if not -1.0 <= self.stiffness <= 1.0:
                    raise ConfigError(f"--agent {text}: stiffness must be in [-1, 1], got {self.stiffness}")
        else:
            self.kind = "trained"
            self.trained = TrainedAgent(text, checkpoint=checkpoint)

    @property
    def label(self) -> str:
        if self.kind == "analytic":
            return "analytic" if self.stiffness is None else f"analytic:{self.stiffness:+.2f}"
        if self.pretrained is not None:
            return f"{self.trained.cfg.algo}:{self.text}"
        return f"{self.trained.cfg.algo}:{Path(self.text).name}"

    @property
    def env_kwargs(self) -> dict:
        return dict(self.trained.cfg.env_kwargs) if self.trained else {}

    def check_task(self, env_id: str) -> None:
        if self.trained is not None and self.trained.env_id != env_id:
            raise RunDirError(f"{self.text} was trained on {self.trained.env_id}, not on {env_id} "
                              f"(give --task {self.trained.env_id})")

    def make(self, env):
        """Build the agent for `env` (the analytic agent reads the env's action mapping)."""
        if self.kind == "trained":
            self.trained.check_env(env)
            return self.trained
        try:
            from vswrist_gym.agents.analytic import AnalyticAgent
        except ImportError as exc:
            raise ConfigError(f"the analytic agent is not available in this installation ({exc})") from None
        if not hasattr(env.unwrapped, "reference_to_action"):
            raise ConfigError(f"the analytic agent needs a VSWrist task; {env.spec.id if env.spec else env} is not one")
        kwargs = {} if self.stiffness is None else {"stiffness": self.stiffness}
        return AnalyticAgent(env, **kwargs)


def run(task: str, agent: str, episodes: int, seeds: list[int], out: str | Path, checkpoint: str = "newest",
        video: str | None = None, argv: list[str] | None = None, trace_episode=None, baseline: bool = True) -> dict:
    """Evaluate and write DIR/metrics.json and DIR/metrics.csv; returns the metrics document. A trained agent is
    scored beside the best constant stiffness on the same episodes (`baseline`; see agents.baseline), stored in
    metrics.json under 'baseline'."""
    from vswrist_gym.agents.procs import limit_threads
    from vswrist_gym.agents.train import task_id

    out = Path(out)
    seeds = check_eval_seeds(seeds, episodes)
    check_new_out(out, allowed=EVAL_OUTPUT_NAMES, what="an evaluation output folder (metrics.json, metrics.csv)")
    if video is not None:
        check_writable(Path(video).parent, "--video")
        if Path(video).is_dir():
            raise ConfigError(f"--video {video} is a folder; give a file name such as episode.mp4")
    env_id = task_id(task)
    spec = AgentSpec(agent, checkpoint=checkpoint)
    spec.check_task(env_id)
    if spec.kind == "trained":  # the analytic agent needs no torch: it is not imported for it
        limit_threads(1)
    header = {"task": env_id, "agent": spec.label, "agent_spec": agent, "checkpoint": checkpoint,
              "episodes_per_seed": episodes, "seeds": list(seeds), "versions": versions()}
    if argv is not None:
        header["command"] = "vswrist evaluate " + shlex.join(argv)
    if spec.trained is not None:
        header["training_seed"] = spec.trained.seed
        header["model_file"] = str(spec.trained.model_path)
        if spec.trained.note:
            header["model_note"] = spec.trained.note
    if video is not None:
        header["video"] = str(video)
    out.mkdir(parents=True, exist_ok=True)
    records, trace = evaluate(env_id, spec.make, seeds, episodes, env_kwargs=spec.env_kwargs,
                              trace_episode=trace_episode, video_path=video, desc=spec.label,
                              on_record=lambda recs: write_partial(out, header, recs))
    summary = summarise(records)
    if baseline and spec.kind == "trained":
        from vswrist_gym.agents.baseline import baseline_summary, best_constant

        best = best_constant(env_id, seeds, episodes, env_kwargs=spec.env_kwargs)
        if best is not None:
            header["baseline"] = baseline_summary(records, best)
    write_metrics(out, header, records, summary)
    return {**header, "summary": summary, "trace": trace}


def format_summary(summary: dict) -> str:
    lines = [f"{'metric':<20} {'unit':<6} {'mean':>11}  95% CI over seeds"]
    for name, s in summary.items():
        if name in TASK_METRICS and s["mean"] != s["mean"]:
            continue  # a task metric this task does not report
        ci = "n/a" if s["low"] != s["low"] else f"[{s['low']:.4g}, {s['high']:.4g}]"
        if name in RATE_METRICS and ci != "n/a":
            ci += f" (Wilson, over {s['n']} episodes)"
        lines.append(f"{name:<20} {METRICS[name][0]:<6} {s['mean']:>11.4g}  {ci}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vswrist evaluate", description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("--task", required=True, help="task id (VSWrist/LoadHold-v0) or short name (LoadHold: its newest version)")
    p.add_argument("--agent", required=True,
                   help="RUN_DIR (from vswrist train), an RL Zoo experiment folder (logs/ppo/VSWrist-Polish-v1_1), "
                        "a model file in either, 'pretrained:TASK[:TRACK]' (a shipped policy), 'analytic' or "
                        "'analytic:STIFFNESS'")
    p.add_argument("--episodes", type=int, default=5, help="episodes per seed (default 5)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="evaluation seeds (default 0-4)")
    p.add_argument("--out", required=True, help="output directory for metrics.json and metrics.csv")
    p.add_argument("--checkpoint", choices=CHECKPOINT_CHOICES, default="newest", help=CHECKPOINT_HELP)
    p.add_argument("--video", help="also write a video of the first episode (e.g. episode.mp4)")
    p.add_argument("--no-baseline", action="store_true",
                   help="do not score a trained agent beside the best constant stiffness on the same episodes")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    try:
        doc = run(args.task, args.agent, args.episodes, args.seeds, args.out, checkpoint=args.checkpoint,
                  video=args.video, argv=argv, baseline=not args.no_baseline)
    except (ConfigError, RunDirError, ValueError) as exc:
        print(f"vswrist evaluate: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # the simulation failed (e.g. SimulationError) during an episode
        partial = Path(args.out) / PARTIAL_FILE
        kept = f"; the episodes finished before it are in {partial}" if partial.is_file() else ""
        print(f"vswrist evaluate: error: the environment failed: {type(exc).__name__}: {exc}{kept}", file=sys.stderr)
        return 1
    except OSError as exc:  # the disk filled or the folder became unwritable during the evaluation
        print(f"vswrist evaluate: error: {exc}", file=sys.stderr)
        return 1
    print(f"{doc['agent']} on {doc['task']}: {args.episodes} episodes x seeds {args.seeds}")
    if "model_file" in doc:
        print(f"model: {doc['model_file']}")
    if "model_note" in doc:
        logger.warning(doc["model_note"])
    print(format_summary(doc["summary"]))
    if "baseline" in doc:
        from vswrist_gym.agents.baseline import format_baseline

        print(format_baseline(doc["baseline"]))
    logger.info(f"wrote {Path(args.out) / 'metrics.json'} and metrics.csv")
    if args.video:
        logger.info(f"wrote {args.video}")
    return 0
