"""One OpenGL render context for every scene of an environment, re-bound to the scene in view.

An environment keeps one compiled MuJoCo scene per catalogue object, so that a scene switch on
reset is a dictionary lookup. A ``mujoco.Renderer`` per scene costs a GL context, full-size
(1280x960) offscreen buffers and a copy of every texture and mesh per object (software GL:
~50 MB and ~0.3 s each). All our scenes share one layout (arena, arm, one object with one mesh
and one texture), so one render context serves them all. Each distinct texture and mesh (keyed
by a digest of its data) is uploaded once, into a GL texture / display list of its own, and a
scene is bound by pointing the context's slots at them: ``MjrContext.texture[i]`` holds a GL
texture name, and the context's display list for mesh ``i`` is recompiled as one call of the
cached list. A switch then costs microseconds instead of re-uploading the object (~13 ms of
CPU in software GL: mipmaps of the cube texture, a display list of ~16k triangles), for a few MB
of GL state per object held; the least recently shown assets beyond ``max_cached_assets`` are
freed. A scene with another layout rebuilds the context.

GL state cannot be pickled or copied: :meth:`SceneRenderer.__getstate__` drops it and the next
:meth:`render` rebuilds it, as Gymnasium's MuJoCo environments do with their renderers. Nor can it
be inherited by a forked child: it is freed just before the process forks and rebuilt on the next
frame (:mod:`scorbot_gym._gl`).
"""

from __future__ import annotations

import contextlib
import hashlib
import weakref
from collections import OrderedDict
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


def _texture(model: mujoco.MjModel, i: int) -> tuple[np.ndarray, ...]:
    """Everything ``mjr_uploadTexture`` reads for texture ``i``."""
    n = model.tex_width[i] * model.tex_height[i] * model.tex_nchannel[i]
    shape = np.array(
        [
            model.tex_type[i],
            model.tex_width[i],
            model.tex_height[i],
            model.tex_nchannel[i],
            model.tex_colorspace[i],
        ]
    )
    return (shape, model.tex_data[model.tex_adr[i] : model.tex_adr[i] + n])


def _mesh(model: mujoco.MjModel, i: int) -> tuple[np.ndarray, ...]:
    """Every array ``mjr_uploadMesh`` reads for mesh ``i`` (its triangles and convex hull)."""
    v, nv = model.mesh_vertadr[i], model.mesh_vertnum[i]
    n, nn = model.mesh_normaladr[i], model.mesh_normalnum[i]
    t, nt = model.mesh_texcoordadr[i], model.mesh_texcoordnum[i]
    f, nf = model.mesh_faceadr[i], model.mesh_facenum[i]
    texcoord = model.mesh_texcoord[t : t + nt] if t >= 0 else model.mesh_texcoord[:0]
    g = model.mesh_graphadr[i]
    if g >= 0:
        hull_nv, hull_nf = model.mesh_graph[g], model.mesh_graph[g + 1]
        hull = model.mesh_graph[g : g + 2 + 3 * hull_nv + 6 * hull_nf]
    else:
        hull = model.mesh_graph[:0]
    return (
        model.mesh_vert[v : v + nv],
        model.mesh_normal[n : n + nn],
        texcoord,
        model.mesh_face[f : f + nf],
        model.mesh_facenormal[f : f + nf],
        model.mesh_facetexcoord[f : f + nf],
        hull,
    )


def _digest(arrays: tuple[np.ndarray, ...]) -> bytes:
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(a.data)
    return h.digest()


class SceneRenderer:
    """Renders RGB, depth and segmentation images of any number of scenes with one GL context.

    ``width`` x ``height`` is the offscreen buffer: every image up to that size is rendered
    into a corner of it; a larger request grows the buffer (the context is rebuilt).
    ``shadows`` turns on the key light's shadow map. ``max_cached_assets`` bounds the textures
    (and, separately, the meshes) kept uploaded beyond the context's own: one of each per object,
    so the default holds a catalogue of 32 objects without re-uploading.
    """

    def __init__(
        self,
        width: int = 320,
        height: int = 240,
        shadows: bool = False,
        max_cached_assets: int = 32,
    ) -> None:
        self.width, self.height = int(width), int(height)
        self.shadows = bool(shadows)
        self.max_cached_assets = int(max_cached_assets)
        if self.max_cached_assets < 0:
            raise ValueError(f"max_cached_assets must be >= 0, got {max_cached_assets}")
        self._digests: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
        self._reset_handles()

    def _reset_handles(self) -> None:
        self._gl: Any = None
        self._con: mujoco.MjrContext | None = None
        self._scene: mujoco.MjvScene | None = None
        self._option = mujoco.MjvOption()
        self._model: mujoco.MjModel | None = None  # the scene bound now
        self._layout: tuple | None = None
        self._own_textures: np.ndarray | None = None  # the context's texture names ...
        self._own_texture_keys: tuple[bytes, ...] = ()  # ... and what they hold
        self._textures: OrderedDict[bytes, int] = OrderedDict()  # digest -> our GL texture
        self._meshes: OrderedDict[bytes, int] = OrderedDict()  # digest -> our 2 display lists
        self._slot_textures: list[bytes] = []  # the digest each context slot shows
        self._slot_meshes: list[bytes] = []

    # --- context management ----------------------------------------------------------------
    @property
    def bound_model(self) -> mujoco.MjModel | None:
        """The model whose textures and meshes are bound now (None before any render)."""
        return self._model

    @property
    def cached_assets(self) -> dict[str, int]:
        """How many textures and meshes are held uploaded beyond the context's own."""
        return {"textures": len(self._textures), "meshes": len(self._meshes)}

    def _asset_digests(self, model: mujoco.MjModel) -> tuple[list[bytes], list[bytes]]:
        found = self._digests.get(model)
        if found is None:
            found = (
                [_digest(_texture(model, i)) for i in range(model.ntex)],
                [_digest(_mesh(model, i)) for i in range(model.nmesh)],
            )
            self._digests[model] = found
        return found

    def _build(self, model: mujoco.MjModel) -> None:
        _gl.prepare_first_context()
        from mujoco.rendering.classic import gl_context

        self._gl = gl_context.GLContext(self.width, self.height)
        _gl.track_gl_owner(self)  # released before a fork (see scorbot_gym._gl)
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
        self._layout = _layout(model)
        # The context's own textures stay (it frees them); its mesh lists are replaced by calls
        # of cached lists when the model is bound next, so that every mesh is in the cache.
        self._own_textures = self._con.texture[: model.ntex].copy()
        self._slot_textures = list(self._asset_digests(model)[0])
        self._own_texture_keys = tuple(self._slot_textures)
        self._slot_meshes = [b""] * model.nmesh

    def _bind_assets(self, model: mujoco.MjModel) -> None:
        """Point the context's texture and mesh slots at ``model``'s assets, uploading each
        asset the first time it is seen."""
        from OpenGL import GL

        con = self._con
        textures, meshes = self._asset_digests(model)
        for i, key in enumerate(textures):
            if self._slot_textures[i] == key:
                continue
            if key == self._own_texture_keys[i]:
                con.texture[i] = self._own_textures[i]
            elif key in self._textures:
                con.texture[i] = self._textures[key]
                self._textures.move_to_end(key)
            else:
                con.texture[i] = self._textures[key] = int(GL.glGenTextures(1))
                mujoco.mjr_uploadTexture(model, con, i)
            self._slot_textures[i] = key
        for i, key in enumerate(meshes):
            if self._slot_meshes[i] == key:
                continue
            lists = self._meshes.get(key)
            if lists is None:
                lists = self._meshes[key] = self._upload_mesh(model, i)
            self._meshes.move_to_end(key)
            for k in range(2):  # the mesh and its convex hull: one call of our lists each
                GL.glNewList(con.baseMesh + 2 * i + k, GL.GL_COMPILE)
                GL.glCallList(lists + k)
                GL.glEndList()
            self._slot_meshes[i] = key
        self._model = model
        self._evict()

    def _upload_mesh(self, model: mujoco.MjModel, i: int) -> int:
        """Compile mesh ``i`` into two new display lists (``mjr_uploadMesh`` writes at
        ``baseMesh + 2 i``, so the base is moved there for the call)."""
        from OpenGL import GL

        con = self._con
        lists = int(GL.glGenLists(2))
        base = con.baseMesh
        try:
            con.baseMesh = lists - 2 * i
            mujoco.mjr_uploadMesh(model, con, i)
        finally:
            con.baseMesh = base
        if model.mesh_graphadr[i] < 0:  # no hull: keep the name as an empty list
            GL.glNewList(lists + 1, GL.GL_COMPILE)
            GL.glEndList()
        return lists

    def _evict(self) -> None:
        from OpenGL import GL

        shown = set(self._slot_textures) | set(self._slot_meshes)
        freed = False
        for cache, delete in (
            (self._textures, lambda name: GL.glDeleteTextures([name])),
            (self._meshes, lambda lists: GL.glDeleteLists(lists, 2)),
        ):
            for key in [k for k in cache if k not in shown][
                : max(0, len(cache) - self.max_cached_assets)
            ]:
                delete(cache.pop(key))
                freed = True
        if freed:
            release_freed_memory()

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
                self._bind_assets(model)
        except Exception as exc:  # mujoco raises several types when no GL context exists
            with contextlib.suppress(Exception):
                self.close()
            self._reset_handles()
            if isinstance(exc, _gl.RenderingUnavailableError):
                raise  # says what is wrong already (a forked child, see scorbot_gym._gl)
            raise _gl.RenderingUnavailableError(
                f"{_gl.INSTALL_HINT} (MUJOCO_GL={_gl.backend_in_use()}: {exc})"
            ) from exc

    def release(self, model: mujoco.MjModel) -> None:
        """Forget ``model`` (its simulation is closed); its uploaded assets stay cached (another
        scene may share them) until evicted."""
        self._digests.pop(model, None)
        if model is self._model:
            self._model = None

    def textures_changed(self, model: mujoco.MjModel) -> None:
        """``model.tex_data`` was edited in place (a texture perturbation): its textures are
        digested again at the next render and the new images uploaded; the old ones stay cached
        (the nominal scene shows them again) until evicted."""
        self.release(model)

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
                from OpenGL import GL

                # The context frees the texture names in its slots: give it back its own.
                self._con.texture[: len(self._own_textures)] = self._own_textures
                if self._textures:
                    GL.glDeleteTextures(list(self._textures.values()))
                for lists in self._meshes.values():
                    GL.glDeleteLists(lists, 2)
                self._con.free()
            self._gl.free()
        self._reset_handles()

    def release_gl(self) -> None:
        """Free the GL state before this process forks (:mod:`scorbot_gym._gl`)."""
        self.close()

    def __getstate__(self) -> dict[str, Any]:
        keep = ("width", "height", "shadows", "max_cached_assets")
        return {name: getattr(self, name) for name in keep}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._digests = weakref.WeakKeyDictionary()
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
