"""Pickling of a VS-Wrist world (``VSWristEnv``'s mixin): the settings and the full episode state travel; the
MuJoCo objects (simulator, model, data, renderer) do not, and are rebuilt on load from the parameters, with the
simulator's state and the model fields that randomisation changes (masses, inertias, frictions) put back, so that
the loaded world steps on as the pickled one would."""

from __future__ import annotations

# what is rebuilt on load rather than pickled: MuJoCo objects, the simulator's classes, and the observation terms
# (closures over this world)
_REBUILT = ("sim", "model", "data", "_renderer", "_viewer", "_WristSim", "_terms", "obs_terms", "_SimulationError")


class PicklingMixin:
    """``__getstate__`` and ``__setstate__``."""

    def __getstate__(self):
        """Pickle the settings and the full episode state; MuJoCo objects are rebuilt on load."""
        state = {k: v for k, v in self.__dict__.items() if k not in _REBUILT}
        state["_sim_state"] = self.sim.get_state()
        state["_model_mutable"] = (self.model.body_mass.copy(), self.model.body_inertia.copy(),
                                   self.model.geom_friction.copy(), self.model.dof_frictionloss.copy())
        return state

    def __setstate__(self, state):
        sim_state = state.pop("_sim_state")
        mass, inertia, friction, frictionloss = state.pop("_model_mutable")
        self.__dict__.update(state)
        self._use_episode_state(self._ep)  # the controller's command and the episode state came back apart
        self._import_simulator()
        self._renderer = None
        self._viewer = None
        self._make_sim(self.params)
        self._scene_ids()
        self.model.body_mass[:] = mass
        self.model.body_inertia[:] = inertia
        self.model.geom_friction[:] = friction
        self.model.dof_frictionloss[:] = frictionloss
        self.sim.set_state(sim_state)
        self._terms = self._obs_terms()
        self.obs_terms = [self._terms[n] for n in self.cfg["observation"]]
