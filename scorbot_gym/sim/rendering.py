"""One OpenGL context for every scene of an environment.

An environment keeps one compiled MuJoCo scene per catalogue object, so that a scene switch on
reset is a dictionary lookup. Giving each scene its own ``mujoco.Renderer`` costs a GL context
(software GL: ~40 MB and ~0.3 s to start) and full-size (1280x960) offscreen buffers per object.
Here the scenes share one GL context; each keeps only its own small MuJoCo render context
(textures, meshes and an offscreen buffer as large as the env's images: ~4-6 MB, ~15 ms to make
on first render), so switching scenes costs nothing. Re-uploading one context's textures and
meshes on every switch instead (``mjr_uploadTexture`` / ``mjr_uploadMesh``) was measured at
~10 ms per switch in software GL, too slow for resets.

GL state cannot be pickled or copied: :meth:`SceneRenderer.__getstate__` drops it and the next
:meth:`render` rebuilds it, as Gymnasium's MuJoCo environments do with their renderers.
"""

from __future__ import annotations

import contextlib
from typing import Any

import mujoco
import numpy as np

from scorbot_gym import _gl

# Geoms in the visual scene: arena (~10), arm (~15), one object, plus decorations; MuJoCo
# drops geoms past this (mjWARN_VGEOMFULL). mujoco.Renderer's 10000 costs ~6 MB per scene.
_MAX_GEOM = 1000
_NO_SHADOW_MAP = 1  # texels per side of the shadow map when shadows are off


class SceneRenderer:
    """Renders RGB, depth and segmentation images of any number of models with one GL context.

    ``width`` x ``height`` is the offscreen buffer: every image up to that size is rendered
    into a corner of it; a larger request grows the buffers (the contexts are rebuilt).
    ``shadows`` turns on the key light's shadow map.
    """

    def __init__(self, width: int = 320, height: int = 240, shadows: bool = False) -> None:
        self.width, self.height = int(width), int(height)
        self.shadows = bool(shadows)
        self._reset_handles()

    def _reset_handles(self) -> None:
        self._gl: Any = None
        # id(model) -> (model, render context, visual scene); the model is kept so that its id
        # is not reused while the entry lives.
        self._contexts: dict[int, tuple[mujoco.MjModel, mujoco.MjrContext, mujoco.MjvScene]] = {}
        self._option = mujoco.MjvOption()

    # --- context management ----------------------------------------------------------------
    @property
    def num_contexts(self) -> int:
        """How many models have render state now."""
        return len(self._contexts)

    def _make_gl(self) -> None:
        from mujoco.rendering.classic import gl_context

        self._gl = gl_context.GLContext(self.width, self.height)
        self._gl.make_current()

    def _make_context(self, model: mujoco.MjModel) -> tuple:
        vis = model.vis
        saved = (vis.global_.offwidth, vis.global_.offheight, vis.quality.shadowsize)
        try:  # the buffers are sized from the model: size them for what is rendered
            vis.global_.offwidth, vis.global_.offheight = self.width, self.height
            if not self.shadows:
                vis.quality.shadowsize = _NO_SHADOW_MAP
            con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100.value)
        finally:
            vis.global_.offwidth, vis.global_.offheight, vis.quality.shadowsize = saved
        con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        scene = mujoco.MjvScene(model, maxgeom=_MAX_GEOM)
        # Shadow mapping triples the cost of a frame in software GL, so it is opt-in.
        scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = self.shadows
        return model, con, scene

    def _bind(self, model: mujoco.MjModel, width: int, height: int) -> tuple:
        if width > self.width or height > self.height:
            self.width, self.height = max(width, self.width), max(height, self.height)
            self.close()
        entry = self._contexts.get(id(model))
        try:
            if self._gl is None:
                self._make_gl()
            self._gl.make_current()
            if entry is None:
                entry = self._contexts[id(model)] = self._make_context(model)
        except Exception as exc:  # mujoco raises several types when no GL context exists
            with contextlib.suppress(Exception):
                self.close()
            self._reset_handles()
            raise _gl.RenderingUnavailableError(
                f"{_gl.INSTALL_HINT} (MUJOCO_GL={_gl.backend_in_use()}: {exc})"
            ) from exc
        # Each render context has its own offscreen framebuffer; bind this one's.
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, entry[1])
        return entry

    def release(self, model: mujoco.MjModel) -> None:
        """Free the render state of one model (e.g. when its simulation is closed)."""
        entry = self._contexts.pop(id(model), None)
        if entry is not None and self._gl is not None:
            self._gl.make_current()
            entry[1].free()

    # --- rendering -------------------------------------------------------------------------
    def render(
        self,
        model: mujoco.MjModel,
        data: mujoco.MjData,
        camera_id: int,
        kind: str = "rgb",
        width: int | None = None,
        height: int | None = None,
    ) -> np.ndarray:
        """``kind="rgb"``: ``uint8 (H, W, 3)``; ``"depth"``: ``float32 (H, W)`` metres along the
        optical axis; ``"segmentation"``: ``int32 (H, W, 2)`` (object id, object type), -1 for
        background (the layout of ``mujoco.Renderer``)."""
        w, h = width or self.width, height or self.height
        _, con, scene = self._bind(model, w, h)
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        cam.fixedcamid = camera_id
        mujoco.mjv_updateScene(
            model, data, self._option, None, cam, mujoco.mjtCatBit.mjCAT_ALL.value, scene
        )
        ids = kind in ("depth", "segmentation")  # flat id colours give exact depth and labels
        scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = ids
        scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = ids
        rect = mujoco.MjrRect(0, 0, w, h)
        mujoco.mjr_render(rect, scene, con)
        if kind == "depth":
            out = np.empty((h, w), np.float32)
            mujoco.mjr_readPixels(None, out, rect, con)
            out = _metric_depth(model, scene, out)
        elif kind == "segmentation":
            rgb = np.empty((h, w, 3), np.uint8)
            mujoco.mjr_readPixels(rgb, None, rect, con)
            out = _segment_ids(scene, rgb)
        else:
            out = np.empty((h, w, 3), np.uint8)
            mujoco.mjr_readPixels(out, None, rect, con)
        return np.ascontiguousarray(out[::-1])  # OpenGL's rows run bottom-up

    # --- lifetime --------------------------------------------------------------------------
    def close(self) -> None:
        """Free all GL state (the next :meth:`render` builds what it needs again)."""
        if self._gl is not None:
            self._gl.make_current()
            for _, con, _ in self._contexts.values():
                con.free()
            self._gl.free()
        self._reset_handles()

    def __getstate__(self) -> dict[str, Any]:
        return {"width": self.width, "height": self.height, "shadows": self.shadows}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._reset_handles()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass


def _metric_depth(model: mujoco.MjModel, scene: mujoco.MjvScene, z: np.ndarray) -> np.ndarray:
    """Undo the reversed-Z projection (the conversion ``mujoco.Renderer`` does)."""
    extent = model.stat.extent
    znear = np.float32(model.vis.map.znear * extent)
    zfar = np.float32(model.vis.map.zfar * extent)
    z64 = z.astype(np.float64)
    if scene.camera[0].orthographic:
        return (zfar - z64 * (zfar - znear)).astype(np.float32)
    c = -(zfar + znear) / (zfar - znear)
    d = -(np.float32(2) * zfar * znear) / (zfar - znear)
    c, d = np.float32(-0.5) * c - np.float32(0.5), np.float32(-0.5) * d
    return (d / (z64 + c)).astype(np.float32)


def _segment_ids(scene: mujoco.MjvScene, rgb: np.ndarray) -> np.ndarray:
    c = rgb.astype(np.int64)
    seg = c[..., 0] | c[..., 1] << 8 | c[..., 2] << 16
    lookup = np.full((scene.ngeom + 1, 2), -1, np.int32)  # seg id 0 is the background
    for g in scene.geoms[: scene.ngeom]:
        if g.segid != -1:
            lookup[g.segid + 1] = (g.objid, g.objtype)
    return lookup[np.minimum(seg, scene.ngeom)]
