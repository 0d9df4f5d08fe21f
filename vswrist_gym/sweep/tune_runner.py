"""Ray Tune execution of a sweep: a grid of trials, or an Optuna search with ASHA early stopping.

Ray starts embedded on this machine (its CPU count as resources) or joins a cluster by address; on a cluster every
node must see the sweep's folders at the same absolute paths (a shared file system) and have this package
installed. A trial asks for one CPU if its run is batched (`vec_env: batch`), else one per env process (`n_envs`); an
analytic baseline for one.

Fault tolerance rests on the run directories, not on Tune's state: a trial whose worker or node died is retried
by Tune (`max_failures`), and the retry resumes the training from the run's newest intact checkpoint; `--resume`
after the driver died starts Tune again on the trials that have no record yet (see `vswrist_gym.sweep.trial`).
A search's `--resume` restores its Tune experiment instead (samples and the Optuna sampler's state); a restarted
sample finds its trainings' run directories and loads (finished) or resumes (cut off) them rather than train again.
"""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

# Tune's experiment state (what `--resume` restores a search from) is saved at most this often; Tune's default,
# 10 s or more, loses with the driver every sample that started and ended between two saves
os.environ.setdefault("TUNE_GLOBAL_CHECKPOINT_S", "2")
SEARCH_METRIC = "eval_return"  # mean over the training seeds of the periodic evaluation (seed + 10,000 episodes)


class ClusterError(RuntimeError):
    """`ray.init(address=...)` failed: one line with what Ray said and what to check."""

    def __init__(self, address: str, exc: Exception, token: str | None):
        what = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        auth = (f"this driver used token authentication ({token})" if token else
                "this driver had no Ray auth token (RAY_AUTH_MODE unset and no ~/.ray/auth_token)")
        super().__init__(f"cannot join the Ray cluster at {address} ({type(exc).__name__}: {what}); {auth}. A "
                         f"cluster started with `ray start` where ~/.ray/auth_token exists uses token "
                         f"authentication (Ray >= 2.52): give this machine that token (RAY_AUTH_TOKEN, or the "
                         f"file from `ray get-auth-token` on the head), or start the cluster with "
                         f"RAY_AUTH_MODE=disabled; see docs/training.md")


def use_cluster_token() -> str | None:
    """Ray (2.52 on) authenticates with a token when `ray start` finds one (~/.ray/auth_token, which any local
    `ray.init()` creates), but a driver given an explicit address never turns it on by itself: it then fails
    after about 40 s of InvalidAuthToken. Where RAY_AUTH_MODE is unset and a token is available, the driver
    uses it, as Ray does for `address='auto'`. Returns where the token came from, or None."""
    if os.environ.get("RAY_AUTH_MODE") is not None:
        return f"RAY_AUTH_MODE={os.environ['RAY_AUTH_MODE']}" if os.environ["RAY_AUTH_MODE"] == "token" else None
    source = ("RAY_AUTH_TOKEN" if os.environ.get("RAY_AUTH_TOKEN") else
              "RAY_AUTH_TOKEN_PATH" if os.environ.get("RAY_AUTH_TOKEN_PATH") else
              "~/.ray/auth_token" if (Path.home() / ".ray" / "auth_token").is_file() else None)
    if source is None:
        return None
    try:  # Ray's own switch: sets RAY_AUTH_MODE=token and refreshes its cached configuration
        from ray._private.authentication.authentication_token_setup import _enable_token_auth
    except ImportError:  # a Ray without token authentication
        return None
    _enable_token_auth()
    return source


def init_ray(address: str | None, log=print) -> dict:
    """Join the cluster at `address`, or start Ray on this machine with its CPUs; returns the cluster resources."""
    import ray

    if ray.is_initialized():
        return ray.cluster_resources()
    if address:
        token = use_cluster_token()
        try:
            ray.init(address=address, log_to_driver=False, configure_logging=False)
        except Exception as exc:  # noqa: BLE001 - Ray raises ConnectionError, AuthenticationError, RuntimeError
            raise ClusterError(address, exc, token) from None
    else:
        # Ray runs its workers at niceness 15 by default: on a shared machine the trials would yield to every other
        # job, where the same `vswrist train` run by hand would not (3.5x slower per trial under a load of 8
        # nice-19 jobs here). 0, an increment: workers keep this process's niceness (`nice vswrist sweep` lowers it)
        os.environ.setdefault("RAY_worker_niceness", "0")
        # address="local": a new instance even when another Ray cluster runs on this machine
        ray.init(address="local", num_cpus=os.cpu_count(), include_dashboard=False, log_to_driver=False,
                 configure_logging=False, _node_ip_address="127.0.0.1")
    res = ray.cluster_resources()
    log(f"Ray {ray.__version__}: {int(res.get('CPU', 0))} CPUs on {len(ray.nodes())} node(s)"
        + (f" at {address}" if address else " (embedded, this machine)"))
    return res


def _progress_callback(total: int, finished_before: int, log):
    from ray import tune

    class Progress(tune.Callback):
        """One line per trial event, with the counts of trials done / running / failed."""

        def _say(self, trials, trial, what):
            # the callback runs before Tune updates `trial`'s own status: count it by the event
            others = [t for t in trials if t is not trial]
            done = finished_before + sum(t.status == "TERMINATED" for t in others) + (what == "finished")
            running = sum(t.status == "RUNNING" for t in others) + (what == "started" or what.startswith("lost"))
            failed = sum(t.status == "ERROR" for t in others) + (what == "FAILED")
            log(f"[sweep {time.strftime('%H:%M:%S')}] {_name(trial)} {what}: {done}/{total} done, {running} running, "
                f"{failed} failed")

        def on_trial_start(self, iteration, trials, trial, **info):
            self._say(trials, trial, "started")

        def on_trial_complete(self, iteration, trials, trial, **info):
            self._say(trials, trial, "finished")

        def on_trial_error(self, iteration, trials, trial, **info):
            self._say(trials, trial, "FAILED")

        def on_trial_recover(self, iteration, trials, trial, **info):
            self._say(trials, trial, "lost its worker; retried from its last checkpoint")

    return Progress()


def _name(trial) -> str:
    cfg = trial.config
    if "trial" in cfg:
        return cfg["trial"]["name"]
    sample = ", ".join(f"{k.replace('__', '.')}={v:.4g}" if isinstance(v, float) else f"{k.replace('__', '.')}={v}"
                       for k, v in cfg.items())
    return f"sample {trial.trial_id} ({sample})"


def _grid_trainable(config):
    from ray import tune

    from vswrist_gym.sweep.trial import run_trial

    import ray

    trial = {**config["trial"], "node": ray.get_runtime_context().get_node_id()}  # recorded: where it ran
    # a batched vec env runs its worlds on this many threads: the CPUs Ray gave the trial, not the machine's
    os.environ["VSWRIST_THREADS"] = str(trial["cpus"])
    result = run_trial(trial, log=lambda msg: print(msg, flush=True))
    tune.report({"return": result.get("return"), "skipped": bool(result.get("skipped"))})


def _check_fits(need: dict, resources: dict) -> None:
    from vswrist_gym.sweep.spec import SweepError

    have = int(resources.get("CPU", 0))
    for name, cpus in need.items():
        if cpus > have:
            raise SweepError(f"trial {name} needs {cpus} CPUs (its n_envs), the Ray cluster has {have}; "
                             f"lower n_envs in the sweep file")


def run_grid(sweep, trials: list[dict], address: str | None, max_concurrent: int | None, log=print) -> list[str]:
    """Run every trial without a record on Ray; returns the names of the trials that failed."""
    from ray import tune

    from vswrist_gym.sweep.trial import read_result

    pending = [t for t in trials if read_result(t) is None]
    finished_before = len(trials) - len(pending)
    if finished_before:
        log(f"{finished_before} of {len(trials)} trials already have a record: not rerun")
    if not pending:
        return []
    resources = init_ray(address, log)
    _check_fits({t["name"]: t["cpus"] for t in pending}, resources)
    trainable = tune.with_resources(_grid_trainable,
                                    lambda config: tune.PlacementGroupFactory([{"CPU": config["trial"]["cpus"]}]))
    storage = (Path(sweep.runs_dir) / "tune").resolve()
    tuner = tune.Tuner(
        trainable, param_space={"trial": tune.grid_search(pending)},
        # reuse_actors: a worker process that finished a trial takes the next one of the same size, so that only
        # the first trial of each pays for importing torch, stable-baselines3 and MuJoCo (seconds per trial)
        tune_config=tune.TuneConfig(max_concurrent_trials=max_concurrent, reuse_actors=True,
                                    trial_dirname_creator=lambda tr: tr.config["trial"]["name"].replace("/", "_")),
        run_config=tune.RunConfig(name=f"grid_{time.strftime('%Y%m%d_%H%M%S')}", storage_path=str(storage),
                                  failure_config=tune.FailureConfig(max_failures=sweep.max_failures),
                                  verbose=0, callbacks=[_progress_callback(len(trials), finished_before, log)]))
    tuner.fit()
    return [t["name"] for t in pending if read_result(t) is None]


# ---------------------------------------------------------------------------------------------------------- search


def _tune_space(space: dict) -> dict:
    from ray import tune

    make = {"uniform": lambda a: tune.uniform(*a), "loguniform": lambda a: tune.loguniform(*a),
            "randint": lambda a: tune.randint(*a), "choice": lambda a: tune.choice(a)}
    return {key.replace(".", "__"): make[kind](args) for key, (kind, args) in space.items()}


def _sampled_entry(base: dict, config: dict) -> dict:
    from vswrist_gym.sweep.spec import set_dotted

    entry = base
    for key, value in config.items():
        value = value.item() if hasattr(value, "item") else value  # NumPy scalars -> plain YAML numbers
        entry = set_dotted(entry, key.replace("__", "."), value)
    return entry


def _eval_curve(run_dir: Path) -> dict[int, float]:
    import numpy as np

    try:
        with np.load(run_dir / "eval" / "evaluations.npz") as ev:
            return {int(t): float(r.mean()) for t, r in zip(ev["timesteps"], ev["results"])}
    except (OSError, ValueError, KeyError):
        return {}


def _search_trainable(config, ctx):
    """One hyperparameter sample: its training seeds run side by side (threads); each new periodic evaluation
    reached by every seed is reported (mean over seeds), so that ASHA can stop a poor sample early."""
    import yaml
    from ray import tune

    from vswrist_gym.agents.runs import atomic_write_text
    from vswrist_gym.sweep.trial import _train

    trial_dir = Path(ctx["root"]) / tune.get_context().get_trial_id()
    trial_dir.mkdir(parents=True, exist_ok=True)
    entry = _sampled_entry(ctx["entry"], config)
    hp_file = trial_dir / "hparams.yaml"
    atomic_write_text(hp_file, yaml.safe_dump({ctx["env_id"]: entry}, sort_keys=False))
    errors: list[BaseException] = []

    def one(seed):
        try:
            _train({"env_id": ctx["env_id"], "algo": ctx["algo"], "seed": seed, "run_dir": str(trial_dir / f"seed{seed}"),
                    "timesteps": ctx["timesteps"], "config": str(hp_file), "n_envs": ctx["n_envs"]},
                   log=lambda msg: None)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the trial's own thread below
            errors.append(exc)

    threads = [threading.Thread(target=one, args=(s,), daemon=True) for s in ctx["seeds"]]
    for th in threads:
        th.start()
    reported = -1

    def common_curve():
        curves = [_eval_curve(trial_dir / f"seed{s}") for s in ctx["seeds"]]
        common = sorted(set.intersection(*(set(c) for c in curves))) if all(curves) else []
        return [(t, sum(c[t] for c in curves) / len(curves)) for t in common]

    while any(th.is_alive() for th in threads):
        time.sleep(1.0)
        for t, mean in common_curve():
            # a report at the full budget makes ASHA stop the trial (max_t) and Tune end its process: it waits
            # for the trainings to save their models and mark their runs finished
            if reported < t < ctx["timesteps"]:
                reported = t
                tune.report({SEARCH_METRIC: mean, "timesteps": t})
    if errors:
        raise errors[0]
    curve = common_curve()
    if curve:  # the end of training: its last evaluation, at the full budget
        tune.report({SEARCH_METRIC: curve[-1][1], "timesteps": ctx["timesteps"]})


def run_search(sweep, address: str | None, resume: bool, max_concurrent: int | None, log=print) -> list[Path]:
    """One Optuna search (through Tune, with ASHA stopping) per task x algo on the training seeds; the best
    sample's entry is written to the sweep's best_out file. Returns the files written."""
    from ray import tune
    from ray.tune.schedulers import ASHAScheduler
    from ray.tune.search.optuna import OptunaSearch

    from vswrist_gym.sweep.best import write_best_entry

    resources = init_ray(address, log)
    written = []
    for env_id in sweep.env_ids:
        task = env_id.split("/")[-1].rsplit("-v", 1)[0]
        for algo in sweep.algos:
            name = f"search_{task}_{algo}"
            storage = (Path(sweep.runs_dir) / "tune").resolve()
            marker = Path(sweep.runs_dir) / task / f"{name}.done.json"
            if marker.is_file():
                log(f"{name}: finished earlier ({json.loads(marker.read_text())['best_out']}): not rerun")
                continue
            cpus = sweep.cpus(algo, env_id) * len(sweep.seeds)
            _check_fits({name: cpus}, resources)
            budget = sweep.budget(algo, env_id)
            ctx = {"env_id": env_id, "algo": algo, "seeds": list(sweep.seeds), "timesteps": budget,
                   "n_envs": sweep.n_envs.get(algo), "entry": sweep.entries[(algo, env_id)],
                   "root": str((Path(sweep.runs_dir) / task / "search" / algo).resolve())}
            trainable = tune.with_resources(tune.with_parameters(_search_trainable, ctx=ctx), {"cpu": cpus})
            path = storage / name
            total = sweep.search["samples"]
            if resume and tune.Tuner.can_restore(str(path)):
                log(f"{name}: resuming the search in {path}")
                tuner = tune.Tuner.restore(str(path), trainable, resume_unfinished=True, resume_errored=True)
            else:
                tuner = tune.Tuner(
                    trainable, param_space=_tune_space(sweep.search["space"][algo]),
                    tune_config=tune.TuneConfig(
                        metric=SEARCH_METRIC, mode="max", num_samples=total, max_concurrent_trials=max_concurrent,
                        search_alg=OptunaSearch(seed=sweep.search["seed"]),
                        scheduler=ASHAScheduler(time_attr="timesteps", max_t=budget,
                                                grace_period=min(sweep.search["grace_steps"], budget),
                                                reduction_factor=2)),
                    run_config=tune.RunConfig(name=name, storage_path=str(storage), verbose=0,
                                              failure_config=tune.FailureConfig(max_failures=sweep.max_failures),
                                              callbacks=[_progress_callback(total, 0, log)]))
            grid = tuner.fit()
            full = [r for r in grid if r.metrics and r.error is None and r.metrics.get("timesteps", 0) >= budget]
            if not full:
                log(f"{name}: no sample finished its {budget} steps; nothing written")
                continue
            best = max(full, key=lambda r: r.metrics[SEARCH_METRIC])
            entry = _sampled_entry(ctx["entry"], best.config)
            entry["n_timesteps"] = budget
            out = sweep.best_out(algo)
            comment = (f"vswrist sweep {sweep.path} (mode: search): best of {len(grid)} samples on training seeds "
                       f"{list(sweep.seeds)},\nperiodic-evaluation return {best.metrics[SEARCH_METRIC]:.4g} "
                       f"(mean over seeds), {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
            write_best_entry(out, algo, env_id, entry, comment=comment if not out.is_file() else "")
            marker.parent.mkdir(parents=True, exist_ok=True)
            plain = lambda cfg: {k: (v.item() if hasattr(v, "item") else v) for k, v in cfg.items()}  # noqa: E731
            # every sample the search counted, by Tune trial id (= its folder under root): a folder that is not
            # here was cut off with the driver before Tune recorded it, and played no part
            marker.write_text(json.dumps({"best_out": str(out), "config": plain(best.config),
                                          SEARCH_METRIC: best.metrics[SEARCH_METRIC], "samples": len(grid),
                                          "trials": {r.metrics.get("trial_id", "?"): {
                                              "config": plain(r.config), SEARCH_METRIC: r.metrics.get(SEARCH_METRIC),
                                              "timesteps": r.metrics.get("timesteps")} for r in grid if r.metrics}},
                                         indent=2))
            log(f"{name}: best {SEARCH_METRIC} {best.metrics[SEARCH_METRIC]:.4g} with {best.config} -> {out} "
                f"[{env_id}]")
            written.append(out)
    return written
