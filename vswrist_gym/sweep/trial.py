"""One grid trial: `vswrist train` (or resume) plus the evaluation protocol of `vswrist compare`, with no Ray in it.

A trial is idempotent, so that Ray may run it again after a worker or the driver died:
- its record `TRIAL_DIR/result.json` is written atomically and last; a trial that has one returns it and runs
  nothing (a finished trial is never rerun, and its results exist once, under its name);
- a training that was cut off continues from its run directory's newest intact checkpoint (`train --resume`);
- the evaluation is rerun whole, over the same seeded episodes, and its metrics files are replaced atomically.
"""

from __future__ import annotations

import json
import os
import socket
import time
from pathlib import Path

RESULT_FILE = "result.json"
TRACE_FILE = "trace.json"
PREVIOUS_PROCESS_WAIT_S = 120.0  # a dead node's processes may take a moment to go


def read_result(trial: dict) -> dict | None:
    path = Path(trial["trial_dir"]) / RESULT_FILE
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _wait_for_previous_process(run_dir: Path, log) -> None:
    """A retried trial may start while the killed attempt's process still winds down: wait for it to go rather
    than fail on `train`'s "being trained by process N" check."""
    from vswrist_gym.agents.runs import process_alive

    deadline = time.time() + PREVIOUS_PROCESS_WAIT_S
    while time.time() < deadline:
        try:
            doc = json.loads((run_dir / "run.json").read_text())
        except (OSError, ValueError):
            return
        proc = doc.get("process") or {}
        if doc.get("status") != "running" or proc.get("pid") == os.getpid() or process_alive(proc) is not True:
            return
        time.sleep(1.0)
    log(f"{run_dir}: process {proc.get('pid')} still holds the run after {PREVIOUS_PROCESS_WAIT_S:.0f} s")


def _train(trial: dict, log) -> str:
    """Train, resume or load the trial's run, as `vswrist compare` plans it; returns what was done."""
    from vswrist_gym.agents.compare import plan_run
    from vswrist_gym.agents.train import train

    run_dir = Path(trial["run_dir"])
    action, wanted = plan_run(trial["env_id"], trial["algo"], trial["seed"], run_dir, trial["timesteps"],
                              trial["config"], retrain=False)
    if action == "load":
        return f"loaded ({wanted} steps)"
    if action == "resume":
        _wait_for_previous_process(run_dir, log)
    start = time.time()
    train(trial["env_id"], trial["algo"], run_dir, config=None if action == "resume" else trial["config"],
          timesteps=wanted, seed=trial["seed"], n_envs=trial.get("n_envs"), resume=action == "resume",
          progress=False, log=log)
    return f"{action} {wanted} steps in {time.time() - start:.0f} s"


def run_trial(trial: dict, log=print) -> dict:
    """Run one grid trial (see `Sweep.trials`) and return its record; a recorded trial is returned unchanged."""
    from vswrist_gym.agents.evaluate import AgentSpec
    from vswrist_gym.agents.protocol import evaluate, json_safe, summarise, write_metrics, write_partial
    from vswrist_gym.agents.runs import TrainedAgent, atomic_write_text, limit_threads

    done = read_result(trial)
    if done is not None:
        return {**done, "skipped": True}
    trial_dir = Path(trial["trial_dir"])
    trial_dir.mkdir(parents=True, exist_ok=True)
    limit_threads(1)
    start = time.time()
    env_id, seeds, episodes = trial["env_id"], trial["eval_seeds"], trial["episodes"]
    trace_at = tuple(trial["trace_at"])
    if trial["kind"] == "learned":
        training = _train(trial, log)
        agent = TrainedAgent(trial["run_dir"])
        label, env_kwargs = trial["algo"].upper(), agent.cfg.env_kwargs

        def make(env, a=agent):
            a.check_env(env)
            return a
    else:
        spec = AgentSpec(f"analytic:{trial['stiffness']}")
        training, label, env_kwargs, make = "analytic (no training)", spec.label, {}, spec.make
    head = {"task": env_id, "agent": label, "seeds": seeds, "episodes_per_seed": episodes, "trial": trial["name"]}
    records, trace = evaluate(env_id, make, seeds, episodes, env_kwargs=env_kwargs, trace_episode=trace_at,
                              on_record=lambda r: write_partial(trial_dir, head, r))
    summary = summarise(records)
    write_metrics(trial_dir, head, records, summary)
    atomic_write_text(trial_dir / TRACE_FILE, json.dumps(json_safe(trace)))
    result = {"trial": trial["name"], "kind": trial["kind"], "agent": label, "training": training,
              "seconds": round(time.time() - start, 1), "host": socket.gethostname(), "pid": os.getpid(),
              "node": trial.get("node"),
              "finished": time.time(), "return": summary["return"]["mean"]}
    atomic_write_text(trial_dir / RESULT_FILE, json.dumps(json_safe(result), indent=2))  # last: the trial is done
    return result
