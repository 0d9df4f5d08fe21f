"""Gymnasium environments of the VS-Wrist, one room per job:

* ``base``: ``VSWristEnv``, one world: construction, reset, the step in three phases (``_begin_step``,
  ``_advance``, ``_finish_step``), divergence handling, rendering, pickling; the task interface (its docstring
  shows how to write a task);
* ``batch``: ``VSWristVectorEnv``, N worlds behind ``gym.make_vec`` with their physics on threads;
* ``actions``: the four action modes and their command maps; ``observations``: the named terms, bounds, noise;
  ``randomization``: domain randomisation at reset; ``rewards``: common reward terms and ``info`` metrics;
* ``shared``: what tasks share (scene helpers, hand geometry, time profiles); ``config``: the YAML settings;
* one module per task (``load_hold``, ``polish``, ``impact``, ``insertion``, ``drill``, ``hammer``, ``throw``).

Make them with ``gymnasium.make("VSWrist/<Task>-vN")`` or ``gymnasium.make_vec(id, N)`` after
``import vswrist_gym``.
"""
