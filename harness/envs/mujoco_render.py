"""Offscreen RGB frames of a MuJoCo env (``render_mode="rgb_array"``), shared by the Sawyer and kitchen envs."""

from __future__ import annotations

import mujoco
import numpy as np

GL_HINT = ("rendering needs an OpenGL backend: set MUJOCO_GL=egl (GPU / headless EGL) or MUJOCO_GL=osmesa "
           "(software) before importing mujoco")


class MujocoRendering:
    """Mixed in before :class:`~harness.envs.base.EarlEnv`: a lazily made ``mujoco.Renderer`` of ``self.model`` at
    ``self._render_size`` (height, width), closed with the env. The env sets ``self._renderer = None``."""

    _renderer: mujoco.Renderer | None
    _render_size: tuple[int, int]

    def _rgb_frame(self, camera) -> np.ndarray:
        """An RGB frame (H, W, 3 uint8) of the current state from ``camera`` (a name or an ``MjvCamera``)."""
        if self.render_mode != "rgb_array":
            raise RuntimeError(f"render() needs render_mode='rgb_array' (got {self.render_mode!r})")
        if self._renderer is None:
            try:
                self._renderer = mujoco.Renderer(self.model, *self._render_size)
            except Exception as e:  # no GL context can be created
                raise RuntimeError(f"cannot create a MuJoCo renderer ({e}); {GL_HINT}") from e
        self._renderer.update_scene(self.data, camera=camera)
        return self._renderer.render()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()
