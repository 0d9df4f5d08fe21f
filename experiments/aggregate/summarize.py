"""Cross-task summary of `vswrist compare` results: one markdown table from DIR/<Task>/summary.json.

    python3 experiments/aggregate/summarize.py [DIR ...]
        (default: experiments/every_task, experiments/long, experiments/long200, experiments/ablation, experiments/ablation_stiffness,
         experiments/long_stiffness, experiments/sac, experiments/sac_tuned, experiments/sac_hammer,
         experiments/sac_hammer_posture_only, experiments/polish_compare, experiments/main_job)

For each task and learned agent: its return and success (mean and Student-t 95 % CI over seeds), the best
fixed-stiffness analytic baseline (highest mean return) with the same, the paired difference in return on the
same episodes, and the verdict on the unpaired intervals. Everything is read from the files; nothing is rerun.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from vswrist_gym.agents.compare import against_baseline, best_baseline

TASK_ORDER = ("Polish", "Drill", "Insertion", "Impact", "LoadHold", "Hammer")


def _ci(s: dict, fmt: str = "{:+.1f}") -> str:
    return f"{fmt.format(s['mean'])} [{fmt.format(s['low'])}, {fmt.format(s['high'])}]"


def rows_of(summary: dict) -> list[dict]:
    rows = summary["rows"]
    best = best_baseline(rows, [k for k in rows if k.startswith("analytic")])
    b = rows[best]
    verdict_text = {"beats": "**better** (CIs do not overlap)", "worse": "worse (CIs do not overlap)",
                    "overlap": "not distinguishable (CIs overlap)", "no CI": "no CI (fewer than two seeds)"}
    out = []
    for agent in (k for k in rows if not k.startswith("analytic")):
        a = rows[agent]
        diff, kind = against_baseline(rows, agent, best)
        verdict = verdict_text[kind]
        out.append({
            "task": summary["task"], "agent": agent, "steps": summary["timesteps"].get(agent.lower()),
            "n": f"{len(summary['seeds'])} x {summary['episodes_per_seed']}",
            "ret": _ci(a["return"]), "succ": _ci(a["success"], "{:.2f}"), "best": best,
            "best_ret": _ci(b["return"]), "best_succ": _ci(b["success"], "{:.2f}"),
            "diff": _ci(diff), "verdict": verdict,
            "train_s": summary["seconds"]["training"],
        })
    return out


def table(result_dir: Path) -> str:
    lines = ["| task | agent | steps/seed | seeds x episodes | training (2 cores) | return | success | "
             "best fixed baseline | its return | its success | paired difference | verdict |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    if (result_dir / "summary.json").is_file():  # one compare output directory (e.g. experiments/polish_compare)
        found = {result_dir.name: result_dir / "summary.json"}
    else:  # one sub-directory per task
        found = {p.parent.name: p for p in result_dir.glob("*/summary.json") if p.parent.name in TASK_ORDER}
    for task in sorted(found, key=lambda t: TASK_ORDER.index(t) if t in TASK_ORDER else len(TASK_ORDER)):
        for r in rows_of(json.loads(found[task].read_text())):
            steps = f"{r['steps']:,}" if r["steps"] else "?"
            lines.append(f"| {r['task']} | {r['agent']} | {steps} | {r['n']} | {r['train_s'] / 60:.1f} min | "
                         f"{r['ret']} | {r['succ']} | {r['best']} | {r['best_ret']} | {r['best_succ']} | "
                         f"{r['diff']} | {r['verdict']} |")
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    defaults = [Path(f"experiments/{d}") for d in ("every_task", "long", "long200", "ablation", "ablation_stiffness", "long_stiffness", "sac", "sac_tuned", "sac_hammer", "sac_hammer_posture_only", "polish_compare", "main_job")]
    dirs = [Path(d) for d in argv] or [p for p in defaults if p.is_dir()]
    for d in dirs:
        print(f"{d}:\n\n{table(d)}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
