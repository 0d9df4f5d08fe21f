"""Run directories: what `vswrist train` writes and how it is read back. The work is done by one module per job,
re-exported here (the names other code and tests import from `vswrist_gym.agents.runs`):

    fileio       atomic writes, output folder checks (RunDirError)
    procs        torch threads, library versions, whether a recorded process still runs
    env_factory  the task id check, the configured VecEnv, frame-stacking and normalisation wrappers
    run_config   config.yaml, run.json, the seed check, command-line overrides
    run_stats    normalisation statistics and the replay buffer as plain arrays
    checkpoints  atomic checkpoints, the newest intact one, the model file
    trained      RL Zoo folders and TrainedAgent

Layout of a run directory written by `vswrist train`:

    config.yaml          the resolved hyperparameter entry (plus env id, algo, seed): re-runnable as is
    run.json             command lines (one per invocation), seed, package versions, status, the training
                         process (pid, host, start time) and a history of ended invocations (finished,
                         interrupted, failed, killed) with the step each reached
    model.zip            final model (written at the end, atomically)
    vecnormalize.npz     final observation/reward normalisation statistics as plain arrays (when normalisation is on)
    checkpoints/step_<N>/{model.zip, vecnormalize.npz, replay_buffer.npz}, checkpoints/latest.json
    eval/evaluations.npz periodic evaluation (learning curve), eval/best_model.zip
    tb/                  TensorBoard logs
    monitor/             per-environment episode logs (Monitor CSV)

What makes a folder a run directory is its `config.yaml`; `vswrist train` refuses to start a new run in a folder
that holds anything else.

Every kept checkpoint holds the SAC replay buffer (its filled part only), so that `--resume --timesteps N`
continues with the transitions the run had, also when it falls back to the older checkpoint; a run that will not
be extended needs only `model.zip` and `vecnormalize.npz`, and its `checkpoints/` may be deleted.

A checkpoint is written into a temporary folder and renamed into place, then `latest.json` is replaced
atomically; an interrupted run therefore never leaves a half-written checkpoint as the latest. `--resume` loads the
newest checkpoint that reads back completely and falls back to an older one when the newest is damaged.

Loading a run's data executes nothing: normalisation statistics and the SAC replay buffer are `.npz` arrays read
with `allow_pickle=False`; a replay buffer pickle (`replay_buffer.pkl`, or any other `.pkl` but normalisation
statistics) is refused unread; an older run's or RL Zoo's `vecnormalize.pkl` is read through an unpickler that
admits only the classes VecNormalize statistics are made of. `model.zip` is stable-baselines3's own format, which
holds pickled objects: a model file is code and must come from a trusted source.
"""

from vswrist_gym.agents.checkpoints import (checkpoint_step, checkpoints, final_model_step, latest_checkpoint,
                                            load_checkpoint, load_model, load_newest_intact, model_bytes,
                                            refuse_pickles, save_checkpoint)
from vswrist_gym.agents.env_factory import (EnvFactory, check_env_id, check_env_kwargs, import_env_package,
                                            make_vec_env, wrap_frame_stack, wrap_normalize)
from vswrist_gym.agents.fileio import (RunDirError, atomic_write_bytes, atomic_write_npz, atomic_write_text,
                                       check_new_out, check_writable, created_root, folder_bytes)
from vswrist_gym.agents.procs import (_proc_start_ticks, limit_threads, process_alive,  # noqa: F401
                                      steps_done, this_process, versions)
from vswrist_gym.agents.run_config import (SEED_MAX, check_seed, override, read_config, update_run_json,
                                           write_config)
from vswrist_gym.agents.run_stats import (REPLAY_ARRAYS, REPLAY_FILE, REPLAY_LEGACY_FILE, VECNORM_FILE,
                                          VECNORM_LEGACY_FILE, VECNORM_PICKLE_ALLOWED, load_replay_buffer,
                                          load_vecnormalize, save_replay_buffer, save_vecnormalize,
                                          vecnormalize_arrays)
from vswrist_gym.agents.trained import (ZOO_ARGS_FILE, ZOO_CONFIG_FILE, ZOO_VECNORM_FILE, TrainedAgent,
                                        env_config_mismatch, read_zoo_run, resolve_agent_path, zoo_params_folder)

__all__ = [
    "REPLAY_ARRAYS", "REPLAY_FILE", "REPLAY_LEGACY_FILE", "SEED_MAX", "VECNORM_FILE", "VECNORM_LEGACY_FILE",
    "VECNORM_PICKLE_ALLOWED", "ZOO_ARGS_FILE", "ZOO_CONFIG_FILE", "ZOO_VECNORM_FILE", "EnvFactory", "RunDirError",
    "TrainedAgent", "atomic_write_bytes", "atomic_write_npz", "atomic_write_text", "check_env_id",
    "check_env_kwargs", "check_new_out", "check_seed", "check_writable", "checkpoint_step", "checkpoints",
    "created_root", "env_config_mismatch", "final_model_step", "folder_bytes", "import_env_package",
    "latest_checkpoint", "limit_threads", "load_checkpoint", "load_model", "load_newest_intact",
    "load_replay_buffer", "load_vecnormalize", "make_vec_env", "model_bytes", "override", "process_alive",
    "read_config", "read_zoo_run", "refuse_pickles", "resolve_agent_path", "save_checkpoint",
    "save_replay_buffer", "save_vecnormalize", "steps_done", "this_process", "update_run_json",
    "vecnormalize_arrays", "versions", "wrap_frame_stack", "wrap_normalize", "write_config", "zoo_params_folder",
]
