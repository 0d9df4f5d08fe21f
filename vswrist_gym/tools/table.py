"""The generated tables of the README and the docs, from the code, the YAML configs and committed outputs.

``python -m vswrist_gym.tools.table --write PATH`` rewrites the blocks of PATH between
``<!-- BEGIN GENERATED: name -->`` and ``<!-- END GENERATED: name -->``; ``--check`` fails if they are stale
(the test suite runs the same check), so the documented tables cannot drift from what produced them.

Blocks: the environment tables (``env-table``, ``tasks``, ``obs-terms``, ``obs-indices``, ``randomisation``),
the shipped policies' table (``pretrained``, from their model cards) and ``compare-table FOLDER``, the table and
verdicts a ``vswrist compare`` run wrote to ``FOLDER/table.md`` (FOLDER relative to the document, so the
document, not the package, names where its results live).
"""

from __future__ import annotations

import argparse
import logging
import re
import sys
from pathlib import Path

logger = logging.getLogger(__name__)


def _envs():
    import gymnasium as gym

    import vswrist_gym

    return [gym.make(env_id).unwrapped for env_id in vswrist_gym.ENV_IDS]


def _older(e) -> str:
    """The task cell of an older version: its newest version and the settings the older id fixes."""
    import vswrist_gym

    short = e.task_id.split("/")[1].rsplit("-v", 1)[0]

    def flat(d, where=""):
        return [x for k, v in d.items()
                for x in (flat(v, f"{where}{k}.") if isinstance(v, dict) else [f"`{where}{k}: {v}`"])]

    fixed = ", ".join(flat(vswrist_gym.ENV_KWARGS[e.task_id]["id_config"]))
    return f"`{vswrist_gym.LATEST[short]}` with {fixed} (an older version, kept registered; CHANGELOG.md)"


def _newest(envs):
    import vswrist_gym

    return [e for e in envs if e.task_id in vswrist_gym.LATEST.values()]


def env_table(envs) -> str:
    """Every registered id, an older version's row naming what it changes."""
    import vswrist_gym

    rows = ["| id | task | action | observation terms | reward terms (weight) | success | episode |",
            "|---|---|---|---|---|---|---|"]
    for e in envs:
        obs = ", ".join(f"`{t.name}`" for t in e.obs_terms)
        rew = ", ".join(f"`{k}` ({w:g})" for k, w in e.reward_weights.items())
        act = f"`{e.cfg['action_mode']}` Box(-1, 1, ({e.action_space.shape[0]},))"
        ep = f"{e.cfg['episode_s']:g} s = {e.episode_steps} steps at {1 / e.ctrl_dt:g} Hz"
        what = e.summary if e.task_id in vswrist_gym.LATEST.values() else _older(e)
        rows.append(f"| `{e.task_id}` | {what} | {act} | {obs} ({e.obs_size} values) | {rew} | "
                    f"{e.success_description()} | {ep} |")
    return "\n".join(rows)


def task_table(envs) -> str:
    """The newest version of every task, in one line each: the README's table."""
    rows = ["| id | task | observation | control, episode |", "|---|---|---|---|"]
    for e in _newest(envs):
        rows.append(f"| `{e.task_id}` | {e.summary} | {e.obs_size} values | "
                    f"{1 / e.ctrl_dt:g} Hz, {e.cfg['episode_s']:g} s |")
    return "\n".join(rows)


def pretrained_table(envs=None) -> str:
    """The shipped policies against the best constant stiffness, from their model cards."""
    from vswrist_gym.tools.ship_policies import cards_table

    return cards_table()


def compare_table(folder: Path) -> str:
    """The table and verdict lines of a ``vswrist compare`` output, as that command wrote them."""
    path = folder / "table.md"
    if not path.is_file():
        raise ValueError(f"compare-table: {path} not found (the folder of a `vswrist compare --out` run)")
    lines = path.read_text().splitlines()
    table = [line for line in lines if line.startswith("|")]
    verdicts = [line for line in lines if line.startswith("- ")]
    return "\n".join(table + [""] + verdicts)


def obs_table(envs) -> str:
    envs = _newest(envs)
    used = {}
    for e in envs:
        for t in e.obs_terms:
            used.setdefault(t.name, []).append(e.task_id.split("/")[1].rsplit("-v", 1)[0])
    terms = {}  # every term any task offers: the common ones first, then each task's own
    for e in envs:
        for name, t in e._terms.items():
            terms.setdefault(name, t)
    rows = ["| term | size | unit | meaning | default in |", "|---|---|---|---|---|"]
    for name, t in terms.items():
        where = ", ".join(used.get(name, [])) or "(available, not default)"
        size = t.size if name != "prev_action" else f"{t.size} (action size)"
        rows.append(f"| `{name}` | {size} | {t.unit} | {t.doc} | {where} |")
    return "\n".join(rows)


def index_table(envs) -> str:
    """Flat-observation indices of every task (the ``obs_slices`` contract)."""
    rows = ["| task | " + " | ".join(["indices"]) + " |", "|---|---|"]
    for e in _newest(envs):
        parts = ", ".join(f"`{n}` {s.start}:{s.stop}" for n, s in e.obs_slices.items())
        rows.append(f"| `{e.task_id}` | {parts} |")
    return "\n".join(rows)


def randomisation_table(envs) -> str:
    rnd = envs[0].cfg["randomize"]
    rows = ["| term | default | range / std |", "|---|---|---|"]
    for name, spec in rnd.items():
        if "range" in spec:
            rng = f"{spec['range'][0]:g} to {spec['range'][1]:g}" + (" s" if name == "latency" else " x nominal")
        else:
            rng = ", ".join(f"{k} {v:g}" for k, v in spec.items() if k != "enabled")
        rows.append(f"| `{name}` | {'on' if spec['enabled'] else 'off'} | {rng} |")
    return "\n".join(rows)


BLOCKS = {"env-table": env_table, "tasks": task_table, "obs-terms": obs_table, "obs-indices": index_table,
          "randomisation": randomisation_table}
README_ONLY = {"tasks"}  # the README's one-line-per-task table; docs/environments.md has the full one
COMPARE = re.compile(r"(<!-- BEGIN GENERATED: compare-table (\S+) -->\n)(?:.*?\n)?"
                     r"(<!-- END GENERATED: compare-table -->)", re.S)


def render_blocks() -> dict[str, str]:
    envs = _envs()
    out = {name: fn(envs) for name, fn in BLOCKS.items()}
    for e in envs:
        e.close()
    return out


def regenerate(path: Path) -> str:
    """PATH's text with every generated block it holds rewritten. ``docs/environments.md`` must hold every
    environment block; other documents hold the blocks they choose."""
    text = path.read_text()
    if any(f"<!-- BEGIN GENERATED: {name} -->" in text for name in BLOCKS):
        text = update(text, render_blocks(), required=path.name == "environments.md")
    if "<!-- BEGIN GENERATED: pretrained -->" in text:
        text = update(text, {"pretrained": pretrained_table()})
    return COMPARE.sub(lambda m: m.group(1) + compare_table(path.parent / m.group(2)) + "\n" + m.group(3), text)


def update(text: str, blocks: dict[str, str], required: bool = True) -> str:
    """Rewrite the generated blocks of ``text``; ``required=False`` skips blocks the text does not hold
    (the README carries only some of them); ``required=True`` asks for every block but the README's own."""
    found = 0
    for name, body in blocks.items():
        pat = re.compile(rf"(<!-- BEGIN GENERATED: {name} -->\n)(?:.*?\n)?(<!-- END GENERATED: {name} -->)", re.S)
        if not pat.search(text):
            if required and name not in README_ONLY:
                raise ValueError(f"block '{name}' markers not found")
            continue
        found += 1
        text = pat.sub(lambda m: m.group(1) + body + "\n" + m.group(2), text)
    if not found:
        raise ValueError("no generated-block markers found")
    return text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("path", nargs="?", default="docs/environments.md")
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--write", action="store_true", help="rewrite the generated blocks in place")
    g.add_argument("--check", action="store_true", help="exit 1 if the generated blocks are stale")
    args = ap.parse_args(argv)
    path = Path(args.path)
    text = path.read_text()
    new = regenerate(path)
    if new == text and "<!-- BEGIN GENERATED:" not in text:
        raise SystemExit(f"{path}: no generated-block markers found")
    if args.write:
        path.write_text(new)
        logger.info(f"{path}: generated blocks updated")
        return 0
    if args.check:
        if new != text:
            print(f"{path}: generated blocks are stale; run python -m vswrist_gym.tools.table --write {path}",
                  file=sys.stderr)
            return 1
        return 0
    print(new)
    return 0


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
