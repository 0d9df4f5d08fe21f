"""Rendering of a VS-Wrist world (``VSWristEnv``'s mixin): ``rgb_array`` frames through an offscreen
``mujoco.Renderer`` (the config's ``render`` camera and size), or MuJoCo's passive viewer for ``human``; both are
made on first use and closed by ``close`` (and when randomisation rebuilds the world's model)."""

from __future__ import annotations

import gymnasium as gym
import mujoco


class RenderMixin:
    """``render``, ``close`` and ``_close_renderer``."""

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        if self.render_mode == "rgb_array":
            if self._renderer is None:
                self._renderer = mujoco.Renderer(self.model, self.cfg["render"]["height"], self.cfg["render"]["width"])
            self.sim.sync()  # brings body poses (and cameras) up to date after a step
            self._renderer.update_scene(self.data, camera=self.cfg["render"]["camera"])
            return self._renderer.render().copy()
        if self._viewer is None:
            import os
            import sys
            has_display = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
            if sys.platform.startswith("linux") and not has_display:
                # MuJoCo's GLFW viewer aborts the whole process without a display; fail cleanly instead
                raise RuntimeError("render_mode='human' needs a display (DISPLAY or WAYLAND_DISPLAY is not set); "
                                   "use render_mode='rgb_array' with MUJOCO_GL=egl on a headless machine")
            from mujoco import viewer as mj_viewer  # needs a display (GLFW)
            self._viewer = mj_viewer.launch_passive(self.model, self.data)
        self._viewer.sync()
        return None

    def _close_renderer(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None

    def close(self):
        self._close_renderer()
