"""One OpenGL context for every scene of an environment, re-bound to the scene being rendered.

An environment keeps one compiled MuJoCo scene per catalogue object (a scene switch on reset is
then a dictionary lookup). Giving each scene its own ``mujoco.Renderer`` costs a GL context, a
render context with full-size offscreen buffers and a copy of every texture and mesh: about
40 MB and 270 ms of software-GL start-up per object. All our scenes share one layout (arena,
arm, one object with one mesh and one texture), so one render context serves them all: when a
different scene is rendered, its textures and meshes are uploaded over the previous ones
(``mjr_uploadTexture`` / ``mjr_uploadMesh``), which is what MuJoCo provides for changing assets
at run time. A scene with a different layout rebuilds the context.

GL state cannot be pickled or copied: :meth:`SceneRenderer.__getstate__` drops it and the next
:meth:`render` rebuilds it, as Gymnasium's MuJoCo environments do with their renderers.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from scorbot_gym import _gl

# Geoms in the visual scene: arena (~10), arm (~15), one object, plus decorations; MuJoCo
# drops geoms past this (mjWARN_VGEOMFULL). mujoco.Renderer's 10000 costs ~6 MB per scene.
_MAX_GEOM = 1000
_NO_SHADOW_MAP = 1  # texels per side of the shadow map when shadows are off


def _layout(model: mujoco.MjModel) -> tuple:
    """What a render context depends on besides the pixels of textures and meshes."""
    return (
        model.ntex,
        tuple(model.tex_type.tolist()),
        model.nmesh,
        model.nhfield,
        model.nskin,
        model.nflex,
        float(model.stat.extent),  # shadow clipping and depth range are scaled by it
    )


class SceneRenderer:
    """Renders RGB, depth and segmentation images of any compatible scene with one GL context.

    ``width`` x ``height`` is the offscreen buffer: every image up to that size is rendered
    into a corner of it; a larger request grows the buffer (a context rebuild, ~0.3 s in
    software GL). ``shadows`` turns on the key light's shadow map.
    """

    def __init__(self, width: int = 320, height: int = 240, shadows: bool = False) -> None:
        self.width, self.height = int(width), int(height)
        self.shadows = bool(shadows)
        self._reset_handles()

    def _reset_handles(self) -> None:
        self._gl: Any = None
        self._con: mujoco.MjrContext | None = None
        self._scene: mujoco.MjvScene | None = None
        self._option = mujoco.MjvOption()
        self._model: mujoco.MjModel | None = None
        self._layout: tuple | None = None

    # --- context management ----------------------------------------------------------------
    @property
    def bound_model(self) -> mujoco.MjModel | None:
        """The model whose assets are on the GPU now (None before the first render)."""
        return self._model

    def _build(self, model: mujoco.MjModel) -> None:
        vis = model.vis
        saved = (vis.global_.offwidth, vis.global_.offheight, vis.quality.shadowsize)
        try:
            from mujoco.rendering.classic import gl_context

            self._gl = gl_context.GLContext(self.width, self.height)
            self._gl.make_current()
            # The buffers are sized from the model; size them for what this env renders.
            vis.global_.offwidth, vis.global_.offheight = self.width, self.height
            if not self.shadows:
                vis.quality.shadowsize = _NO_SHADOW_MAP
            self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100.value)
        except Exception as exc:  # mujoco raises several types when no GL context exists
            self.close()
            raise _gl.RenderingUnavailableError(
                f"{_gl.INSTALL_HINT} (MUJOCO_GL={_gl.backend_in_use()}: {exc})"
            ) from exc
        finally:
            vis.global_.offwidth, vis.global_.offheight, vis.quality.shadowsize = saved
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._con)
        self._con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=_MAX_GEOM)
        # Shadow mapping triples the cost of a frame in software GL, so it is opt-in.
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = self.shadows
        self._model, self._layout = model, _layout(model)

    def _bind(self, model: mujoco.MjModel, width: int, height: int) -> None:
        if width > self.width or height > self.height:
            self.width, self.height = max(width, self.width), max(height, self.height)
            self.close()
        if self._con is None:
            self._build(model)
            return
        self._gl.make_current()
        if model is self._model:
            return
        if _layout(model) != self._layout:
            self.close()
            self._build(model)
            return
        for tex in range(model.ntex):
            mujoco.mjr_uploadTexture(model, self._con, tex)
        for mesh in range(model.nmesh):
            mujoco.mjr_uploadMesh(model, self._con, mesh)
        self._model = model

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
        self._bind(model, w, h)
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        cam.fixedcamid = camera_id
        scene = self._scene
        mujoco.mjv_updateScene(
            model, data, self._option, None, cam, mujoco.mjtCatBit.mjCAT_ALL.value, scene
        )
        ids = kind in ("depth", "segmentation")  # flat id colours give exact depth and labels
        scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = ids
        scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = ids
        rect = mujoco.MjrRect(0, 0, w, h)
        mujoco.mjr_render(rect, scene, self._con)
        if kind == "depth":
            out = np.empty((h, w), np.float32)
            mujoco.mjr_readPixels(None, out, rect, self._con)
            out = self._metric_depth(model, out)
        elif kind == "segmentation":
            rgb = np.empty((h, w, 3), np.uint8)
            mujoco.mjr_readPixels(rgb, None, rect, self._con)
            out = self._segment_ids(rgb)
        else:
            out = np.empty((h, w, 3), np.uint8)
            mujoco.mjr_readPixels(out, None, rect, self._con)
        return np.ascontiguousarray(out[::-1])  # OpenGL's rows run bottom-up

    def _metric_depth(self, model: mujoco.MjModel, z: np.ndarray) -> np.ndarray:
        """Undo the reversed-Z projection (the conversion ``mujoco.Renderer`` does)."""
        extent = model.stat.extent
        znear = np.float32(model.vis.map.znear * extent)
        zfar = np.float32(model.vis.map.zfar * extent)
        z64 = z.astype(np.float64)
        if self._scene.camera[0].orthographic:
            return (zfar - z64 * (zfar - znear)).astype(np.float32)
        c = -(zfar + znear) / (zfar - znear)
        d = -(np.float32(2) * zfar * znear) / (zfar - znear)
        c, d = np.float32(-0.5) * c - np.float32(0.5), np.float32(-0.5) * d
        return (d / (z64 + c)).astype(np.float32)

    def _segment_ids(self, rgb: np.ndarray) -> np.ndarray:
        c = rgb.astype(np.int64)
        seg = c[..., 0] | c[..., 1] << 8 | c[..., 2] << 16
        scene = self._scene
        lookup = np.full((scene.ngeom + 1, 2), -1, np.int32)  # seg id 0 is the background
        for g in scene.geoms[: scene.ngeom]:
            if g.segid != -1:
                lookup[g.segid + 1] = (g.objid, g.objtype)
        return lookup[np.minimum(seg, scene.ngeom)]

    # --- lifetime --------------------------------------------------------------------------
    def close(self) -> None:
        """Free the GL state (the next :meth:`render` builds it again)."""
        if self._con is not None and self._gl is not None:
            self._gl.make_current()
            self._con.free()
        if self._gl is not None:
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
