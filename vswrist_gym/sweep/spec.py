"""Sweep files: which trials a sweep runs, checked completely before Ray (or anything else) starts.

A sweep file is YAML. Paths in it are relative to the directory `vswrist sweep` runs in (the repository root for
the committed sweeps). Keys (every other key is an error that names it):

    mode: grid | search        grid: one trial per task x algo x seed, plus the analytic baselines;
                               search: a hyperparameter search per task x algo on the training seeds
    tasks: [Polish, ...]       task ids or VSWrist short names
    algos: [ppo, sac]          learned agents ([] for baselines only)
    seeds: [0, 1, 2]           training seeds; in a grid also the evaluation seeds, as in `vswrist compare`
    episodes: 10               protocol evaluation episodes per seed (grid)
    stiffness: [-1, ..., 1]    fixed stiffness commands of the analytic baseline trials (grid; [] for none)
    timesteps: {ppo: 100000}   training steps per seed (default: the config's n_timesteps)
    n_envs: {ppo: 2}           environments per run (default: the config's n_envs); also the trial's CPUs,
                               except for a batched run (vec_env: batch), which asks for one
    configs: {ppo: FILE}       hyperparameter file (default: the packaged configs/<algo>.yaml)
    overrides: {ppo: {...}}    merged into every task's entry (ablations), e.g.
                               {env_kwargs: {residual: {stiffness_scale: 0.0}}}
    out: results               tables and plots: OUT/<Task>/ (the layout `vswrist compare --out` writes)
    runs_dir: runs/results     run directories and trial records: RUNS_DIR/<Task>/
    max_failures: 3            retries of a trial whose worker died (each resumes from the last checkpoint)
    search:                    (search only)
      samples: 16              hyperparameter samples (Tune trials) per task x algo
      space: {sac: {learning_rate: {loguniform: [1.0e-4, 1.0e-3]}, gamma: {choice: [0.9, 0.95, 0.99]}}}
                               keys are entry keys (dotted for fields of a mapping: env_kwargs.residual.x;
                               a value written as RL Zoo's "dict(...)" string is searched whole, with choice);
                               distributions: uniform, loguniform, randint [low, high), choice
      grace_steps: 5000        training steps before a poor sample may be stopped (ASHA)
      seed: 0                  seed of the Optuna sampler
      best_out: FILE           where the best entries are written (default RUNS_DIR/best_<algo>.yaml)
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from vswrist_gym.agents.hparams import ALGO_NAMES, ConfigError, load_config, read_mapping, resolve_entry


class SweepError(ConfigError):
    """A sweep file, or the state of its output folders, does not allow the sweep to run."""


TOP_KEYS = ("mode", "tasks", "algos", "seeds", "episodes", "stiffness", "timesteps", "n_envs", "configs",
            "overrides", "out", "runs_dir", "max_failures", "search")
SEARCH_KEYS = ("samples", "space", "grace_steps", "seed", "best_out")
DISTRIBUTIONS = ("uniform", "loguniform", "randint", "choice")
SEARCH_SEED_MAX = 900_000  # training, periodic-evaluation (+10,000) seeds stay below the protocol's (1,000,000+)


def _int(value, key: str, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low or (high is not None and value > high):
        span = f"[{low}, {high}]" if high is not None else f">= {low}"
        raise SweepError(f"'{key}' must be an integer {span}, got {value!r}")
    return value


def _list(value, key: str) -> list:
    if not isinstance(value, list):
        raise SweepError(f"'{key}' must be a list, got {value!r}")
    return value


def _per_algo(doc: dict, key: str, algos: list[str]) -> dict:
    value = doc.get(key) or {}
    if not isinstance(value, dict):
        raise SweepError(f"'{key}' must map algorithms ({', '.join(ALGO_NAMES)}) to values, got {value!r}")
    for algo in value:
        if algo not in algos:
            raise SweepError(f"'{key}.{algo}': not one of this sweep's algos {algos}")
    return value


def deep_merge(base: dict, changes: dict, where: str = "") -> dict:
    """`base` with `changes` merged in, mappings key by key (an ablation changes one field of env_kwargs). A
    mapping merged into a value that is not one (RL Zoo's "dict(...)" string of policy_kwargs) is refused rather
    than allowed to replace the whole value."""
    out = copy.deepcopy(base)
    for k, v in changes.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v, f"{where}{k}.")
        elif isinstance(v, dict) and k in out and out[k] is not None:
            raise SweepError(f"'{where}{k}' is {out[k]!r} in the hyperparameter file, not a mapping: give its whole "
                             f"value instead of some of its fields")
        else:
            out[k] = copy.deepcopy(v)
    return out


def set_dotted(entry: dict, key: str, value) -> dict:
    """A copy of `entry` with `value` at the dotted path `key` (policy_kwargs.log_std_init)."""
    *head, last = key.split(".")
    return deep_merge(entry, _nest(head, {last: value}))


def _nest(head: list[str], leaf: dict) -> dict:
    for k in reversed(head):
        leaf = {k: leaf}
    return leaf


def _short(env_id: str) -> str:
    return env_id.split("/")[-1].rsplit("-v", 1)[0]


def _distribution(spec, key: str) -> tuple[str, list]:
    if not isinstance(spec, dict) or len(spec) != 1 or next(iter(spec)) not in DISTRIBUTIONS:
        raise SweepError(f"'{key}' must be one of {{{': [...]}, {'.join(DISTRIBUTIONS)}: [...]}}, got {spec!r}")
    kind, args = next(iter(spec.items()))
    if kind == "choice":
        if not isinstance(args, list) or not args:
            raise SweepError(f"'{key}.choice' must be a non-empty list, got {args!r}")
        return kind, args
    if (not isinstance(args, list) or len(args) != 2 or not all(isinstance(a, (int, float)) and not isinstance(a, bool)
                                                                 for a in args) or not args[0] < args[1]):
        raise SweepError(f"'{key}.{kind}' must be [low, high] with low < high, got {args!r}")
    if kind == "loguniform" and args[0] <= 0:
        raise SweepError(f"'{key}.loguniform' needs low > 0, got {args[0]}")
    if kind == "randint" and not all(isinstance(a, int) for a in args):
        raise SweepError(f"'{key}.randint' needs integer bounds, got {args!r}")
    return kind, args


@dataclass
class Sweep:
    """A checked sweep file; `trials()` lists what it runs."""

    path: Path
    mode: str
    env_ids: list[str]
    algos: list[str]
    seeds: list[int]
    episodes: int
    stiffness: list[float]
    timesteps: dict
    n_envs: dict
    configs: dict
    overrides: dict
    out: Path
    runs_dir: Path
    max_failures: int
    search: dict = field(default_factory=dict)
    entries: dict = field(default_factory=dict)  # (algo, env_id) -> the entry the sweep trains (overrides merged)
    doc: dict = field(default_factory=dict)

    def entry_file(self, algo: str) -> Path:
        """The hyperparameter file the sweep's runs of `algo` read: written by `write_entry_files`."""
        return self.runs_dir / "configs" / f"{algo}.yaml"

    def write_entry_files(self) -> None:
        from vswrist_gym.agents.runs import atomic_write_text

        for algo in self.algos:
            data = {env_id: self.entries[(algo, env_id)] for env_id in self.env_ids}
            path = self.entry_file(algo)
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, yaml.safe_dump(data, sort_keys=False))

    def budget(self, algo: str, env_id: str) -> int:
        return int(self.timesteps.get(algo) or self.entries[(algo, env_id)]["n_timesteps"])

    def cpus(self, algo: str, env_id: str) -> int:
        """CPUs a trial asks Ray for: one for a batched run (``vec_env: batch``: its worlds step on one thread, and
        a grid's parallelism comes from trials side by side), else one per environment process (``n_envs``)."""
        entry = self.entries[(algo, env_id)]
        if entry.get("vec_env", "batch") == "batch" and env_id.startswith("VSWrist/"):
            return 1
        return int(self.n_envs.get(algo) or entry.get("n_envs", 1))

    def trials(self) -> list[dict]:
        """Every grid trial as a plain (JSON-able) dict; absolute paths, since Ray workers run elsewhere."""
        out = []
        trace_at = [self.seeds[0], 0]
        for env_id in self.env_ids:
            task = _short(env_id)
            base = {"task": task, "env_id": env_id, "episodes": self.episodes, "trace_at": trace_at}
            for algo in self.algos:
                for s in self.seeds:
                    name = f"{algo}_seed{s}"
                    out.append({**base, "kind": "learned", "name": f"{task}/{name}", "algo": algo, "seed": s,
                                "eval_seeds": [s], "timesteps": self.budget(algo, env_id),
                                "n_envs": self.n_envs.get(algo), "config": str(self.entry_file(algo).resolve()),
                                "run_dir": str((self.runs_dir / task / name).resolve()),
                                "trial_dir": str((self.runs_dir / task / "trials" / name).resolve()),
                                "cpus": self.cpus(algo, env_id)})
            for k in self.stiffness:
                name = f"analytic_{k:+.2f}"
                out.append({**base, "kind": "analytic", "name": f"{task}/{name}", "stiffness": k,
                            "eval_seeds": list(self.seeds),
                            "trial_dir": str((self.runs_dir / task / "trials" / name).resolve()), "cpus": 1})
        return out

    def best_out(self, algo: str) -> Path:
        given = self.search.get("best_out")
        if given:
            p = Path(given)
            return p if len(self.algos) == 1 else p.with_name(f"{p.stem}_{algo}{p.suffix}")
        return self.runs_dir / f"best_{algo}.yaml"


def load_sweep(path: str | Path) -> Sweep:
    """Read and check a sweep file; every error is one line naming the key (SweepError)."""
    path = Path(path)
    if not path.is_file():
        raise SweepError(f"sweep file {path}: file not found (sweep files are not package data: the studies' sweep "
                         f"files are in the repository's experiments/<study>/, listed in experiments/README.md)")
    try:
        return _load(path)
    except SweepError as exc:
        raise SweepError(f"sweep file {path}: {exc}") from None
    except ConfigError as exc:  # from the hyperparameter loader: already names the key
        raise SweepError(f"sweep file {path}: {exc}") from None


def _load(path: Path) -> Sweep:
    from vswrist_gym.agents.protocol import EVAL_SEED_MAX, check_eval_seeds
    from vswrist_gym.agents.runs import SEED_MAX

    doc = read_mapping(path, SweepError, TOP_KEYS, ("tasks", "seeds"), "mode, tasks, algos, seeds, ...")
    mode = doc.get("mode", "grid")
    if mode not in ("grid", "search"):
        raise SweepError(f"'mode' must be 'grid' or 'search', got {mode!r}")

    from vswrist_gym.agents.train import task_id

    env_ids = []
    for t in _list(doc["tasks"], "tasks"):
        if not isinstance(t, str):
            raise SweepError(f"'tasks' holds {t!r}, not a task name")
        try:
            env_ids.append(task_id(t))
        except ConfigError as exc:
            raise SweepError(f"'tasks': {exc}") from None
    if not env_ids:
        raise SweepError("'tasks' must name at least one task")
    if len(set(env_ids)) != len(env_ids):
        raise SweepError("'tasks' names a task twice")
    algos = _list(doc.get("algos", list(ALGO_NAMES)), "algos")
    for a in algos:
        if a not in ALGO_NAMES:
            raise SweepError(f"'algos': unknown algorithm {a!r}; allowed: {', '.join(ALGO_NAMES)}")
    if len(set(algos)) != len(algos):
        raise SweepError("'algos' names an algorithm twice")
    seed_max = EVAL_SEED_MAX if mode == "grid" else SEED_MAX
    seeds = [_int(s, "seeds", 0, min(seed_max, SEED_MAX)) for s in _list(doc["seeds"], "seeds")]
    if not seeds or len(set(seeds)) != len(seeds):
        raise SweepError("'seeds' must list at least one seed, each once")
    episodes = _int(doc.get("episodes", 10), "episodes", 1)
    try:
        check_eval_seeds(seeds if mode == "grid" else [0], episodes)
    except ValueError as exc:
        raise SweepError(f"'episodes': {exc}") from None
    stiffness = _list(doc.get("stiffness", [-1.0, -0.5, 0.0, 0.5, 1.0] if mode == "grid" else []), "stiffness")
    for k in stiffness:
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not -1.0 <= k <= 1.0:
            raise SweepError(f"'stiffness' values must be numbers in [-1, 1], got {k!r}")
    if mode == "search" and stiffness:
        raise SweepError("'stiffness': a search trains learned agents only; leave the analytic baselines to a grid")
    timesteps = _per_algo(doc, "timesteps", algos)
    for a, v in timesteps.items():
        _int(v, f"timesteps.{a}", 1)
    n_envs = _per_algo(doc, "n_envs", algos)
    for a, v in n_envs.items():
        _int(v, f"n_envs.{a}", 1)
    configs = _per_algo(doc, "configs", algos)
    overrides = _per_algo(doc, "overrides", algos)
    for a, v in overrides.items():
        if not isinstance(v, dict):
            raise SweepError(f"'overrides.{a}' must be a mapping of entry keys, got {v!r}")
    for key in ("out", "runs_dir"):
        if key in doc and not isinstance(doc[key], str):
            raise SweepError(f"'{key}' must be a folder path, got {doc[key]!r}")
    max_failures = _int(doc.get("max_failures", 3), "max_failures", 0, 100)

    entries = {}
    for a in algos:
        file = Path(configs[a]) if a in configs else None
        if file is not None and not file.is_absolute():
            file = Path.cwd() / file
        for env_id in env_ids:
            base = load_config(a, env_id, file).raw  # checks the file and that it has the task
            entry = deep_merge(base, overrides.get(a, {}), f"overrides.{a}.")
            try:
                resolve_entry(a, env_id, entry, source=f"overrides.{a}")
            except ConfigError as exc:
                raise SweepError(f"'overrides.{a}': {exc}") from None
            entries[(a, env_id)] = entry

    search = {}
    if mode == "search":
        search = _check_search(doc.get("search"), algos, env_ids, entries, seeds)
    elif "search" in doc:
        raise SweepError("'search' is only read with mode: search")
    sweep = Sweep(path=path, mode=mode, env_ids=env_ids, algos=algos, seeds=seeds, episodes=episodes,
                  stiffness=[float(k) for k in stiffness], timesteps=timesteps, n_envs=n_envs, configs=configs,
                  overrides=overrides, out=Path(doc.get("out", f"runs/sweep/{path.stem}")),
                  runs_dir=Path(doc.get("runs_dir", f"runs/sweep/{path.stem}/runs")), max_failures=max_failures,
                  search=search, entries=entries, doc=doc)
    if mode == "search":
        for a in algos:
            for env_id in env_ids:
                top = max(seeds) + sweep.cpus(a, env_id) + 10_000
                if top >= SEARCH_SEED_MAX + 10_000:
                    raise SweepError(f"'seeds': a search trains on seeds below {SEARCH_SEED_MAX} so that its "
                                     f"environments never meet the protocol's evaluation episodes")
    return sweep


def _check_search(search, algos, env_ids, entries, seeds) -> dict:
    if not isinstance(search, dict):
        raise SweepError("'search' is required with mode: search (samples, space, ...)")
    unknown = [k for k in search if k not in SEARCH_KEYS]
    if unknown:
        raise SweepError(f"unknown key 'search.{unknown[0]}'; allowed: {', '.join(SEARCH_KEYS)}")
    out = {"samples": _int(search.get("samples", 8), "search.samples", 1, 10_000),
           "grace_steps": _int(search.get("grace_steps", 1), "search.grace_steps", 1),
           "seed": _int(search.get("seed", 0), "search.seed", 0), "best_out": search.get("best_out")}
    if out["best_out"] is not None and not isinstance(out["best_out"], str):
        raise SweepError(f"'search.best_out' must be a file path, got {out['best_out']!r}")
    space = search.get("space")
    if not isinstance(space, dict) or not space:
        raise SweepError("'search.space' must map each algo to its distributions")
    for a in space:
        if a not in algos:
            raise SweepError(f"'search.space.{a}': not one of this sweep's algos {algos}")
    for a in algos:
        dists = space.get(a)
        if not isinstance(dists, dict) or not dists:
            raise SweepError(f"'search.space.{a}' must map entry keys to distributions")
        checked = {}
        for key, spec in dists.items():
            kind, args = _distribution(spec, f"search.space.{a}.{key}")
            checked[key] = (kind, args)
        for env_id in env_ids:  # every end of every range must make a valid entry
            for pick in (0, -1):
                entry = entries[(a, env_id)]
                for key, (kind, args) in checked.items():
                    value = args[pick] if kind != "randint" else args[0] if pick == 0 else args[1] - 1
                    entry = set_dotted(entry, key, value)
                try:
                    resolve_entry(a, env_id, entry, source=f"search.space.{a}")
                except ConfigError as exc:
                    raise SweepError(f"'search.space.{a}': {exc}") from None
        out.setdefault("space", {})[a] = checked
    if not all(math.isfinite(s) for s in seeds):
        raise SweepError("'seeds' must be finite")
    return out
