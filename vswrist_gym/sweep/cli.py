"""`vswrist sweep SWEEP.yaml [--address ADDR] [--resume] [--max-concurrent K]`: run a sweep file on Ray.

A grid trains and evaluates every task x algo x seed (and evaluates the analytic baselines) as Ray Tune trials,
then writes per task the table, summary and plots `vswrist compare` writes. A search (`mode: search`) tunes
hyperparameters on the training seeds and writes the best entry to a hyperparameter file. The sweep file format
is described in `vswrist_gym.sweep.spec`; the committed sweeps are in experiments/.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time

from vswrist_gym.sweep import RAY_INSTALL_HINT

RECORD_FILE = "sweep.json"  # in runs_dir: the sweep file's content, to refuse mixing two sweeps in one folder


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="vswrist sweep", description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("sweep", metavar="SWEEP.yaml", help="sweep file (e.g. experiments/every_task/every_task.yaml)")
    p.add_argument("--address", help="join this Ray cluster (e.g. 10.0.0.5:6379, or 'auto'); default: start Ray "
                                     "on this machine with its CPUs")
    p.add_argument("--resume", action="store_true",
                   help="continue a sweep whose driver stopped: trials with a record are not rerun, cut-off "
                        "trainings continue from their last checkpoint")
    p.add_argument("--max-concurrent", type=int, metavar="K", help="at most K trials at a time (default: as many "
                                                                   "as the CPUs allow)")
    return p


def ray_available() -> bool:
    try:
        import optuna  # noqa: F401
        import ray  # noqa: F401
        from ray import tune  # noqa: F401
    except ImportError:
        return False
    return True


def check_state(sweep, resume: bool) -> None:
    """A new sweep needs a runs_dir without another sweep's record; --resume needs this sweep's record."""
    from vswrist_gym.agents.compare import COMPARE_OUTPUT_NAMES
    from vswrist_gym.agents.runs import check_new_out, check_writable
    from vswrist_gym.sweep.spec import SweepError

    record = sweep.runs_dir / RECORD_FILE
    mine = json.dumps(sweep.doc, sort_keys=True, default=str)
    if record.is_file():
        theirs = json.dumps(json.loads(record.read_text())["sweep"], sort_keys=True)
        if not resume:
            raise SweepError(f"runs_dir {sweep.runs_dir} already holds a sweep ({record}); continue it with "
                             f"--resume or set another runs_dir")
        if theirs != mine:
            raise SweepError(f"the sweep file changed since the sweep in {sweep.runs_dir} started; resume it with "
                             f"the same file, or set another runs_dir")
    elif resume:
        raise SweepError(f"--resume: no sweep in {sweep.runs_dir} ({RECORD_FILE} is missing; nothing to resume)")
    check_writable(sweep.runs_dir, "runs_dir")
    if sweep.mode == "grid":
        for env_id in sweep.env_ids:
            check_new_out(sweep.out / env_id.split("/")[-1].rsplit("-v", 1)[0], allowed=COMPARE_OUTPUT_NAMES,
                          what="a vswrist compare output folder", name="out")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    from vswrist_gym.agents.hparams import ConfigError
    from vswrist_gym.agents.runs import RunDirError, atomic_write_text
    from vswrist_gym.sweep.spec import load_sweep

    try:
        if args.max_concurrent is not None and args.max_concurrent <= 0:
            raise ConfigError(f"--max-concurrent must be a positive integer, got {args.max_concurrent}")
        sweep = load_sweep(args.sweep)
        if args.address and args.address.rsplit(":", 1)[0] in ("127.0.0.1", "localhost"):
            # Ray replaces a loopback address by this machine's network address, where a cluster started on
            # 127.0.0.1 does not listen; this keeps the driver on loopback (read when ray is imported)
            os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
        if not ray_available():
            print(f"vswrist sweep: error: {RAY_INSTALL_HINT}", file=sys.stderr)
            return 2
        check_state(sweep, args.resume)
    except (ConfigError, RunDirError, ValueError) as exc:
        print(f"vswrist sweep: error: {exc}", file=sys.stderr)
        return 2
    command = "vswrist sweep " + shlex.join(argv)
    t0, load_start = time.time(), os.getloadavg()[0]
    if args.address:
        from vswrist_gym.sweep.tune_runner import ClusterError, init_ray

        try:  # the cluster first: a sweep that cannot start writes nothing (a rerun needs no --resume)
            init_ray(args.address)
        except ClusterError as exc:
            print(f"vswrist sweep: error: {exc}", file=sys.stderr)
            return 2
    sweep.runs_dir.mkdir(parents=True, exist_ok=True)
    record = sweep.runs_dir / RECORD_FILE
    if not record.is_file():
        atomic_write_text(record, json.dumps({"sweep": sweep.doc, "file": str(sweep.path), "command": command,
                                              "started": time.time()}, indent=2, default=str))
    sweep.write_entry_files()
    try:
        if sweep.mode == "search":
            from vswrist_gym.sweep.tune_runner import run_search

            written = run_search(sweep, args.address, args.resume, args.max_concurrent)
            print(f"best hyperparameters: {', '.join(map(str, written)) or 'none (no sample finished)'}")
            return 0 if written else 1
        from vswrist_gym.sweep.summary import write_summaries
        from vswrist_gym.sweep.tune_runner import run_grid

        trials = sweep.trials()
        failed = run_grid(sweep, trials, args.address, args.max_concurrent)
        write_summaries(sweep, trials, time.time() - t0, load_start, command)
        print(f"{len(trials) - len(failed)}/{len(trials)} trials done in {time.time() - t0:.0f} s; "
              f"tables in {sweep.out}/<Task>/table.md")
        if failed:
            print(f"vswrist sweep: {len(failed)} trial(s) failed: {', '.join(failed)}; rerun with --resume",
                  file=sys.stderr)
            return 1
        return 0
    except (ConfigError, RunDirError) as exc:
        print(f"vswrist sweep: error: {exc}", file=sys.stderr)
        return 2
    finally:
        import ray

        if ray.is_initialized():
            ray.shutdown()
