"""Episode state of N worlds as (N, ...) arrays, one structure for the single env (N = 1) and the batch, and the
step's updates of it as functions, state in, state out (over arrays of worlds, or one world's numbers).

``EpisodeState`` holds

* the world's springs (``spring_K``, N m; ``spring_delta0``, rad: the sinh law's constants, ``stiffness.SpringLaw``;
  each world's own where randomisation draws them at reset);
* the step under way: its action (``action`` (N, action dim): clipped to [-1, 1]), the motor references it
  commands (``theta`` (N, 4): A, B, C, PS, rad) and the controller's command behind them: the clipped posture
  reference (``command`` (N, 3): RUD, FE, PS, rad) and the internal torque (``lam``, N m: the stiffness preload, as
  the observation and the info report it). The command is the controller's state: each world's
  ``AnalyticController`` keeps it in its row (``AnalyticController.bind``), so a batch that computes its worlds'
  commands over arrays writes them here in one operation and each controller goes on from them;
* whether the physics of the last control period diverged (``diverged``: MuJoCo found the state unstable and
  reset it; the simulator's message stays with the world, ``_sim_error``; ``ending``);
* the episode's actuation latency (``latency``: the substeps at the start of each control period that still run
  on the previous motor references, drawn at reset; ``held_substeps``);
* the episode's clock (``step``: control steps taken, ``t``: time, s), whether it has ended (``ended``: its last
  step terminated or truncated it, or it has not begun; a world's ``step`` then needs a ``reset``), and its
  contact record (``peak_contact``: the largest contact force, N; ``sum_contact_sq``: the sum of its squares, N^2);
* the step's measures (``posture`` (N, 3): RUD, FE, PS, rad; ``defl`` (N, 3): the spring deflections, rad;
  ``energy``: their stored energy, J; ``contact``: the task's contact force, N; ``closure``: the period's
  loop-closure opening, m or rad);
* the posture reference: the episode's table (``references`` (N, steps + 1, 3): the reference at each control
  instant k ctrl_dt, rad, computed at reset) and the step's row of it (``target`` (N, 3));
* the previous action (``prev_action`` (N, action dim), float32: the last step's clipped action, as observed);
* the sensor noise: the episode's draws (``noise`` (N, steps + 1, 13): one row per observation, drawn at reset;
  ``observations.ObservationsMixin._draw_noise_table``) and the current observation's row (``nz`` (N, 13)); read
  only where the task's sensor noise is on;
* the history that the success criteria read (``history_error`` (N, steps, 3): the posture error, rad;
  ``history_energy`` (N, steps), J; ``history_contact`` (N, steps), N): row j holds step j + 1, so a world's
  first ``step`` rows are its episode so far;
* the task's own state (``task``: a ``TaskState`` of the fields its ``task_state`` declares, drawn by its reset
  and read, or written, by its hooks over arrays of worlds: ``hooks``).

A batch owns one of N worlds and each of its worlds holds a one-world view of it (``share``), so that the batch
updates every world with one array operation and the world reads its own row, with nothing copied between them.
The single env owns one of a world and writes its row; its attributes (``_step``, ``_t``, ``_posture``, ...:
``EpisodeStateMixin``) read it. A task's hooks written over arrays of worlds (``hooks``) read and write the rows of
the worlds they are given, the single env's being ``ONE``.
"""

from __future__ import annotations

import numpy as np

ONE = slice(0, 1)  # the single env's rows of its state: it runs the code written over arrays of worlds on its one


class TaskState:
    """A task's episode state of N worlds: each field its ``task_state`` declares ({name: (the shape of one world's
    value, dtype)}) as an (N, ...) array, so that its hooks read and write every world's in one operation."""

    def __init__(self, n: int, fields: dict):
        for name, (shape, dtype) in fields.items():
            setattr(self, name, np.zeros((n,) + tuple(shape), dtype=dtype))

    def put(self, ids, **values) -> None:
        """The new state of the worlds ``ids`` (an index, a slice or an array of them): ``values`` {field: array}."""
        for f, v in values.items():
            getattr(self, f)[ids] = v

    def row(self, i: int) -> TaskState:
        """World i's state: (1, ...) views of these arrays."""
        out = TaskState.__new__(TaskState)
        for f, v in vars(self).items():
            setattr(out, f, v[i:i + 1])
        return out

    @staticmethod
    def concatenate(states: list) -> TaskState:
        """One state of the worlds of ``states``, in order."""
        out = TaskState.__new__(TaskState)
        for f in vars(states[0]):
            setattr(out, f, np.concatenate([getattr(s, f) for s in states]))
        return out


def task_field(name: str) -> property:
    """A world's read-only attribute over its row of task-state field ``name``: a Python number (a one-number
    field) or a view of the row (an array field), for the task's per-world code (its reference, its scene) and the
    tools that read an episode's draws."""
    def get(self):
        v = getattr(self._ep.task, name)
        return v.item(0) if v.ndim == 1 else v[0]
    return property(get, doc=f"This world's ``{name}`` (its row of the task state).")


class EpisodeState:
    """The (N, ...) arrays of N worlds' episode state (see the module docstring); a new one is all zeros, its
    episodes ended (none has begun)."""

    FIELDS = ("spring_K", "spring_delta0", "action", "theta", "command", "lam", "diverged", "latency", "step", "t", "ended",
              "peak_contact", "sum_contact_sq", "posture", "defl", "energy", "contact", "closure", "references",
              "target", "prev_action", "noise", "nz", "history_error", "history_energy", "history_contact")
    __slots__ = FIELDS + ("task",)

    def __init__(self, n: int, steps: int, n_act: int, task_fields: dict | None = None):
        """``n`` worlds whose episodes last ``steps`` control steps, with actions of ``n_act`` numbers, of a task
        whose own state has ``task_fields`` (``TaskState``)."""
        self.task = TaskState(n, task_fields or {})
        self.spring_K = np.zeros(n)
        self.spring_delta0 = np.zeros(n)
        self.action = np.zeros((n, n_act))
        self.theta = np.zeros((n, 4))
        self.command = np.zeros((n, 3))
        self.lam = np.zeros(n)
        self.diverged = np.zeros(n, dtype=bool)
        self.latency = np.zeros(n, dtype=np.int64)
        self.step = np.zeros(n, dtype=np.int64)
        self.t = np.zeros(n)
        self.ended = np.ones(n, dtype=bool)
        self.peak_contact = np.zeros(n)
        self.sum_contact_sq = np.zeros(n)
        self.posture = np.zeros((n, 3))
        self.defl = np.zeros((n, 3))
        self.energy = np.zeros(n)
        self.contact = np.zeros(n)
        self.closure = np.zeros(n)
        self.references = np.zeros((n, steps + 1, 3))
        self.target = np.zeros((n, 3))
        self.prev_action = np.zeros((n, n_act), dtype=np.float32)
        self.noise = np.zeros((n, steps + 1, 13))
        self.nz = np.zeros((n, 13))
        self.history_error = np.zeros((n, steps, 3))
        self.history_energy = np.zeros((n, steps))
        self.history_contact = np.zeros((n, steps))

    # what a new episode starts from zero, before its reset's draws (the latency is drawn after this); the other
    # fields are the reset's (references, noise, springs) or each step's, and the history is read up to ``step``
    CLEARED = ("step", "t", "latency", "peak_contact", "sum_contact_sq", "posture", "defl", "energy", "contact",
               "closure", "target", "prev_action")

    def clear(self, rows) -> None:
        """The state a new episode starts from, in the worlds ``rows`` (an index or an array of them): the task's
        own included, which its reset then draws."""
        for f in self.CLEARED:
            getattr(self, f)[rows] = 0
        for v in vars(self.task).values():
            v[rows] = 0

    def row(self, i: int) -> EpisodeState:
        """World i's state: (1, ...) views of these arrays (writes to either are seen by both)."""
        out = EpisodeState.__new__(EpisodeState)
        for f in self.FIELDS:
            setattr(out, f, getattr(self, f)[i:i + 1])
        out.task = self.task.row(i)
        return out

    def put(self, ids, **values) -> None:
        """The new state of the worlds ``ids`` (their rows, or (rows, columns)): ``values`` {field: array}."""
        for f, v in values.items():
            getattr(self, f)[ids] = v

    def __getstate__(self):
        return {f: getattr(self, f) for f in self.FIELDS + ("task",)}

    def __setstate__(self, state):
        for f in self.FIELDS + ("task",):
            setattr(self, f, state[f])


def share(worlds: list) -> EpisodeState:
    """One state of ``worlds`` (each holding its own, ``_ep``) with their current values; each world's ``_ep``
    becomes its row of it."""
    out = EpisodeState.__new__(EpisodeState)
    for f in EpisodeState.FIELDS:
        setattr(out, f, np.concatenate([getattr(e._ep, f) for e in worlds]))
    out.task = TaskState.concatenate([e._ep.task for e in worlds])
    for i, e in enumerate(worlds):
        e._use_episode_state(out.row(i))
    return out


def tick(step, dt: float):
    """The clock after a control period of ``dt`` s: (step, time) from the steps taken before."""
    k = step + 1
    return k, k * dt


def held_substeps(latency, step):
    """The substeps of the coming control period that run on the previous motor references, of worlds with
    ``latency`` (substeps) that have taken ``step`` steps: none in an episode's first period, which has no previous
    references (the reset's settling ran on the initial ones)."""
    return latency * (step > 0)


def record_contact(peak, sum_sq, contact):
    """The contact record after a step with ``contact`` (N): (the largest force so far, the sum of the squares).
    The peak keeps its value unless the new force exceeds it (a NaN force leaves it as it was)."""
    return np.where(contact > peak, contact, peak), sum_sq + contact * contact


def record_history(ep: EpisodeState, ids, steps, err) -> None:
    """The history of the worlds ``ids`` (an array of rows, or one row) after their step ``steps`` (its count): the
    step's posture error ``err`` and their stored energy and contact force (their measures, already stored)."""
    j = steps - 1
    ep.history_error[ids, j] = err
    ep.history_energy[ids, j] = ep.energy[ids]
    ep.history_contact[ids, j] = ep.contact[ids]


def at_step(ep: EpisodeState, ids, table) -> np.ndarray:
    """The worlds ``ids``' entries (L, ...) of ``table`` (N, steps + 1, ...: a value at each control instant of the
    episode, as ``references``) at their steps, to read (the single env's, ``ONE``, is a view of its row: a basic
    index, which costs a fraction of an array one on every step)."""
    if ids is ONE:
        return table[ONE, ep.step.item(0)]
    return table[ids if isinstance(ids, np.ndarray) else np.arange(len(table))[ids], ep.step[ids]]


def episode_history(ep: EpisodeState, ids) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The episode so far of the worlds ``ids``, which have taken the same number of steps k (the success criteria
    read it at the episode's last step): their posture errors (L, k, 3), stored energies (L, k) and contact forces
    (L, k)."""
    steps = ep.step[ids]
    k = steps.item(0)
    if (steps != k).any():
        raise ValueError(f"the worlds' histories differ in length ({steps.tolist()} steps)")
    return ep.history_error[ids, :k], ep.history_energy[ids, :k], ep.history_contact[ids, :k]


class EpisodeStateMixin:
    """``VSWristEnv``'s attributes over its row of the episode state (``self._ep``), read-only: the numbers of one
    world as Python numbers, as the tasks' hooks read them, and its vectors as views of its row. The state is
    written through ``_ep`` (``_nz`` excepted: a test replaces the noise draws through it)."""

    def _use_episode_state(self, ep: EpisodeState) -> None:
        """Hold ``ep`` (one world's rows) as this world's episode state, with its controller's command in it."""
        self._ep = ep
        self.ctrl.bind(ep.command[0], ep.lam)

    @property
    def _a(self) -> np.ndarray:
        return self._ep.action[0]

    @property
    def _theta(self) -> np.ndarray:
        return self._ep.theta[0]

    @property
    def _latency(self) -> float:
        """The episode's actuation latency (s)."""
        return self._ep.latency.item(0) * float(self.model.opt.timestep)

    @property
    def _step(self) -> int:
        return self._ep.step.item(0)

    @property
    def _t(self) -> float:
        return self._ep.t.item(0)

    @property
    def _needs_reset(self) -> bool:
        return self._ep.ended.item(0)

    @property
    def _peak_contact(self) -> float:
        return self._ep.peak_contact.item(0)

    @property
    def _sum_contact_sq(self) -> float:
        return self._ep.sum_contact_sq.item(0)

    @property
    def _posture(self) -> np.ndarray:
        return self._ep.posture[0]

    @property
    def _defl(self) -> np.ndarray:
        return self._ep.defl[0]

    @property
    def _energy(self) -> float:
        return self._ep.energy.item(0)

    @property
    def _contact(self) -> float:
        return self._ep.contact.item(0)

    @property
    def _closure(self) -> float:
        return self._ep.closure.item(0)

    @property
    def _target(self) -> np.ndarray:
        return self._ep.target[0]

    @property
    def _references(self) -> np.ndarray:
        return self._ep.references[0]

    @property
    def _prev_action(self) -> np.ndarray:
        return self._ep.prev_action[0]

    @property
    def _noise(self) -> np.ndarray | None:
        """The episode's sensor noise table (None: no sensor noise)."""
        return None if self._noise_std is None else self._ep.noise[0]

    @property
    def _nz(self) -> np.ndarray | None:
        """The current observation's sensor noise draws (13,) (None: no sensor noise)."""
        return None if self._noise_std is None else self._ep.nz[0]

    @_nz.setter
    def _nz(self, value) -> None:
        self._ep.nz[0] = value

    @property
    def _history(self) -> dict[str, np.ndarray]:
        """The episode so far (what the success criteria read): {"error": (step, 3), "energy", "contact": (step,)}
        views of this world's rows."""
        ep = self._ep
        k = ep.step.item(0)
        return {"error": ep.history_error[0, :k], "energy": ep.history_energy[0, :k],
                "contact": ep.history_contact[0, :k]}
