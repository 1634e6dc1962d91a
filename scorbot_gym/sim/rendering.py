"""One OpenGL render context for every scene of an environment, re-bound to the scene in view.

An environment keeps one compiled MuJoCo scene per catalogue object, so that a scene switch on
reset is a dictionary lookup. A ``mujoco.Renderer`` per scene costs a GL context, full-size
(1280x960) offscreen buffers and a copy of every texture and mesh per object (software GL:
~50 MB and ~0.3 s each). All our scenes share one layout (arena, arm, one object with one mesh
and one texture), so one render context serves them all: when another scene is rendered, the
textures and meshes that differ are uploaded over the previous ones (``mjr_uploadTexture`` /
``mjr_uploadMesh``, MuJoCo's way to change assets at run time); a scene with another layout
rebuilds the context. A switch then costs one object's upload (~10 ms in software GL, paid only
by resets that change object and render) instead of ~8 MB per object of resident GL state, the
alternative measured in ``benchmarks/env_memory.py``.

GL state cannot be pickled or copied: :meth:`SceneRenderer.__getstate__` drops it and the next
:meth:`render` rebuilds it, as Gymnasium's MuJoCo environments do with their renderers.
"""

from __future__ import annotations

import contextlib
from typing import Any

import mujoco
import numpy as np

from scorbot_gym import _gl
from scorbot_gym.sim._memory import release_freed_memory

# Geoms in the visual scene: arena (~10), arm (~15), one object, plus decorations; MuJoCo
# drops geoms past this (mjWARN_VGEOMFULL). mujoco.Renderer's 10000 costs ~6 MB per scene.
_MAX_GEOM = 1000
_NO_SHADOW_MAP = 1  # texels per side of the shadow map when shadows are off


def _layout(model: mujoco.MjModel) -> tuple:
    """What a render context depends on besides the pixels of textures and the meshes."""
    return (
        model.ntex,
        tuple(model.tex_type.tolist()),
        model.nmesh,
        model.nhfield,
        model.nskin,
        model.nflex,
        float(model.stat.extent),  # shadow clipping and depth range are scaled by it
    )


def _texture(model: mujoco.MjModel, i: int) -> np.ndarray:
    n = model.tex_width[i] * model.tex_height[i] * model.tex_nchannel[i]
    return model.tex_data[model.tex_adr[i] : model.tex_adr[i] + n]


def _mesh(model: mujoco.MjModel, i: int) -> tuple[np.ndarray, ...]:
    """Every array ``mjr_uploadMesh`` reads for mesh ``i``."""
    v, nv = model.mesh_vertadr[i], model.mesh_vertnum[i]
    n, nn = model.mesh_normaladr[i], model.mesh_normalnum[i]
    t, nt = model.mesh_texcoordadr[i], model.mesh_texcoordnum[i]
    f, nf = model.mesh_faceadr[i], model.mesh_facenum[i]
    texcoord = model.mesh_texcoord[t : t + nt] if t >= 0 else model.mesh_texcoord[:0]
    return (
        model.mesh_vert[v : v + nv],
        model.mesh_normal[n : n + nn],
        texcoord,
        model.mesh_face[f : f + nf],
        model.mesh_facenormal[f : f + nf],
        model.mesh_facetexcoord[f : f + nf],
    )


def _same(a: tuple | np.ndarray, b: tuple | np.ndarray) -> bool:
    if isinstance(a, np.ndarray):
        return a.shape == b.shape and np.array_equal(a, b)
    return all(_same(x, y) for x, y in zip(a, b, strict=True))


class SceneRenderer:
    """Renders RGB, depth and segmentation images of any number of scenes with one GL context.

    ``width`` x ``height`` is the offscreen buffer: every image up to that size is rendered
    into a corner of it; a larger request grows the buffer (the context is rebuilt).
    ``shadows`` turns on the key light's shadow map.
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
        self._model: mujoco.MjModel | None = None  # whose assets the context holds now
        self._layout: tuple | None = None

    # --- context management ----------------------------------------------------------------
    @property
    def bound_model(self) -> mujoco.MjModel | None:
        """The model whose textures and meshes are uploaded now (None before any render)."""
        return self._model

    def _build(self, model: mujoco.MjModel) -> None:
        _gl.prepare_first_context()
        from mujoco.rendering.classic import gl_context

        self._gl = gl_context.GLContext(self.width, self.height)
        self._gl.make_current()
        vis = model.vis
        saved = (vis.global_.offwidth, vis.global_.offheight, vis.quality.shadowsize)
        try:  # the buffers are sized from the model: size them for what is rendered
            vis.global_.offwidth, vis.global_.offheight = self.width, self.height
            if not self.shadows:
                vis.quality.shadowsize = _NO_SHADOW_MAP
            self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100.value)
        finally:
            vis.global_.offwidth, vis.global_.offheight, vis.quality.shadowsize = saved
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._con)
        self._con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=_MAX_GEOM)
        # Shadow mapping triples the cost of a frame in software GL, so it is opt-in.
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = self.shadows
        self._model, self._layout = model, _layout(model)

    def _upload(self, model: mujoco.MjModel) -> None:
        """Replace the assets of the bound model that differ in ``model``."""
        old = self._model
        for i in range(model.ntex):
            if old is None or not _same(_texture(model, i), _texture(old, i)):
                mujoco.mjr_uploadTexture(model, self._con, i)
        for i in range(model.nmesh):
            if old is None or not _same(_mesh(model, i), _mesh(old, i)):
                mujoco.mjr_uploadMesh(model, self._con, i)
        self._model = model
        release_freed_memory()  # the replaced GL storage: ~10 MB over many switches otherwise

    def _bind(self, model: mujoco.MjModel, width: int, height: int) -> None:
        if width > self.width or height > self.height:
            self.width, self.height = max(width, self.width), max(height, self.height)
            self.close()
        try:
            if self._con is not None and _layout(model) != self._layout:
                self.close()
            if self._con is None:
                self._build(model)
            self._gl.make_current()
            if model is not self._model:
                self._upload(model)
        except Exception as exc:  # mujoco raises several types when no GL context exists
            with contextlib.suppress(Exception):
                self.close()
            self._reset_handles()
            raise _gl.RenderingUnavailableError(
                f"{_gl.INSTALL_HINT} (MUJOCO_GL={_gl.backend_in_use()}: {exc})"
            ) from exc

    def release(self, model: mujoco.MjModel) -> None:
        """Forget ``model`` (its simulation is closed): the next scene rendered uploads all of
        its assets rather than compare them with a model that may be freed."""
        if model is self._model:
            self._model = None

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
        con, scene = self._con, self._scene
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
        """Free the GL state (the next :meth:`render` builds it again)."""
        if self._gl is not None:
            self._gl.make_current()
            if self._con is not None:
                self._con.free()
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
