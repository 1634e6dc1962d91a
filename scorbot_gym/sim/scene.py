"""Compose the tabletop scene from MJCF pieces: arena, table, arm, cameras and one object.

Everything is in metres. The world origin is on the floor under the robot; the robot base sits on
the table top at ``(0, 0, TABLE_HEIGHT)`` and faces +x, where the workspace is.
"""

from __future__ import annotations

from collections.abc import Sequence

from scorbot_gym import _gl
from scorbot_gym.assets.textures import encode_png
from scorbot_gym.objects import ObjectSpec
from scorbot_gym.sim.arm import build_arm
from scorbot_gym.sim.cameras import CameraSpec

mjcf = _gl.import_mjcf()  # dm_control with its own renderer off (see _gl)

TABLE_HEIGHT = 0.75
# Where objects are placed: reachable with a vertical grasp and inside the top camera's view.
WORKSPACE_X = (0.22, 0.34)
WORKSPACE_Y = (-0.12, 0.12)
_WS_CX = sum(WORKSPACE_X) / 2
# Largest image any camera renders (MuJoCo's offscreen framebuffer limit in the model).
MAX_RENDER_WIDTH, MAX_RENDER_HEIGHT = 1280, 960

DEFAULT_CAMERAS: tuple[CameraSpec, ...] = (
    # Above the workspace looking straight down; image up = away from the robot.
    CameraSpec(
        "top",
        (_WS_CX, 0.0, TABLE_HEIGHT + 0.62),
        (_WS_CX, 0.0, TABLE_HEIGHT),
        30.0,
        up=(1.0, 0.0, 0.0),
    ),
    CameraSpec(
        "side", (_WS_CX, -0.62, TABLE_HEIGHT + 0.22), (_WS_CX, 0.0, TABLE_HEIGHT + 0.03), 32.0
    ),
    CameraSpec(
        "overview", (0.95, -0.75, TABLE_HEIGHT + 0.65), (0.18, 0.0, TABLE_HEIGHT + 0.15), 45.0
    ),
)


def _arena(cameras: Sequence[CameraSpec]) -> mjcf.RootElement:
    arena = mjcf.RootElement(model="scorbot_tabletop")
    arena.compiler.angle = "radian"
    arena.option.timestep = 0.002
    arena.option.integrator = "implicitfast"
    arena.option.cone = "elliptic"
    arena.option.impratio = 10
    arena.visual.quality.shadowsize = 1024  # used only with shadows=True
    arena.visual.quality.offsamples = 0
    arena.visual.map.znear = 0.01
    arena.visual.map.zfar = 5.0  # x extent (2 m): nothing is farther than 10 m
    getattr(arena.visual, "global").offwidth = MAX_RENDER_WIDTH
    getattr(arena.visual, "global").offheight = MAX_RENDER_HEIGHT
    arena.visual.headlight.ambient = [0.35, 0.35, 0.35]
    arena.visual.headlight.diffuse = [0.4, 0.4, 0.4]

    arena.asset.add(
        "texture",
        name="floor_tex",
        type="2d",
        builtin="checker",
        width=256,
        height=256,
        rgb1=[0.3, 0.32, 0.35],
        rgb2=[0.25, 0.27, 0.3],
    )
    arena.asset.add("material", name="floor_mat", texture="floor_tex", texrepeat=[6, 6])
    arena.asset.add(
        "texture",
        name="table_tex",
        type="2d",
        builtin="flat",
        width=64,
        height=64,
        rgb1=[0.62, 0.6, 0.56],
        rgb2=[0.6, 0.58, 0.55],
        mark="random",
        random=0.02,
        markrgb=[0.55, 0.53, 0.5],
    )
    arena.asset.add("material", name="table_mat", texture="table_tex", texrepeat=[4, 4])

    wb = arena.worldbody
    wb.add(
        "light",
        name="key",
        pos=[0.6, -0.4, TABLE_HEIGHT + 1.6],
        dir=[-0.3, 0.25, -1],
        diffuse=[0.6, 0.6, 0.6],
        castshadow=True,
    )
    wb.add(
        "light",
        name="fill",
        pos=[0.2, 0.8, TABLE_HEIGHT + 1.2],
        dir=[0, -0.5, -1],
        diffuse=[0.25, 0.25, 0.25],
        castshadow=False,
    )
    wb.add(
        "geom",
        name="floor",
        type="plane",
        size=[3, 3, 0.1],
        material="floor_mat",
        contype=0,
        conaffinity=0,
    )
    table = wb.add("body", name="table", pos=[0.15, 0, TABLE_HEIGHT])
    table.add(
        "geom",
        name="table_top",
        type="box",
        size=[0.45, 0.5, 0.02],
        pos=[0, 0, -0.02],
        material="table_mat",
        friction=[0.7, 0.005, 0.0001],
        condim=3,
    )
    for i, (x, y) in enumerate(((0.4, 0.45), (0.4, -0.45), (-0.4, 0.45), (-0.4, -0.45))):
        table.add(
            "geom",
            name=f"table_leg{i}",
            type="box",
            size=[0.025, 0.025, TABLE_HEIGHT / 2],
            pos=[x, y, -TABLE_HEIGHT / 2],
            rgba=[0.3, 0.3, 0.3, 1],
            contype=0,
            conaffinity=0,
        )
    for cam in cameras:
        wb.add("camera", name=cam.name, pos=list(cam.pos), xyaxes=cam.xyaxes(), fovy=cam.fovy)
    return arena


def _object(spec: ObjectSpec) -> mjcf.RootElement:
    model = spec.model
    obj = mjcf.RootElement(model=spec.name)
    obj.asset.add("mesh", name="mesh", file=mjcf.Asset(model.stl_bytes(), ".stl"))
    obj.asset.add(
        "texture",
        name="tex",
        type="cube",
        gridsize=[3, 4],
        gridlayout=".U..LFRB.D..",
        file=mjcf.Asset(encode_png(spec.texture_image()), ".png"),
    )
    obj.asset.add("material", name="mat", texture="tex", specular=0.2, shininess=0.2)
    body = obj.worldbody.add("body", name="object")
    body.add(
        "geom",
        name="geom",
        type="mesh",
        mesh="mesh",
        material="mat",
        mass=spec.mass,
        friction=[spec.friction, 0.01, 0.0005],
        condim=4,
        group=1,
    )
    return obj


def build_scene(
    obj: ObjectSpec, cameras: Sequence[CameraSpec] = DEFAULT_CAMERAS
) -> mjcf.RootElement:
    """The whole scene as one MJCF model: arena + arm + a free object."""
    names = [c.name for c in cameras]
    if len(set(names)) != len(names):
        raise ValueError(f"camera names must be unique, got {names}")
    arena = _arena(cameras)
    base = arena.worldbody.add("site", name="robot_base", pos=[0, 0, TABLE_HEIGHT], group=5)
    base.attach(build_arm())
    frame = arena.worldbody.attach(_object(obj))
    frame.pos = [WORKSPACE_X[0] + 0.06, 0.0, TABLE_HEIGHT + 0.1]
    frame.add("freejoint", name="free")
    return arena


# --- scenes with several objects ---------------------------------------------------------------
#: geom group of an object that is out of the scene: not drawn (MuJoCo's default visual option
#: shows groups 0-2), so a parked object appears in no image, background frames included
HIDDEN_GROUP = 3
VISIBLE_OBJECT_GROUP = 1
SUPPORT_NAME = "support"


def parking_position(index: int) -> tuple[float, float, float]:
    """Where object ``index`` of a multi-object scene waits while it is not on the table: under
    the floor (no camera sees below it) and 0.4 m from the next one, so parked objects never
    touch anything."""
    return (-1.5 + 0.4 * index, 2.0, -0.5)


def _support(arena: mjcf.RootElement) -> None:
    """A kinematic (mocap) stand: an inclined plate with a lip at its lower edge, on which an
    object rests tilted, like a part leaning in a fixture. Parked under the floor until a task
    puts it on the table; its plate and lip sizes are set per episode in the compiled model."""
    arena.asset.add("material", name="support_mat", rgba=[0.45, 0.42, 0.38, 1], specular=0.1)
    body = arena.worldbody.add("body", name=SUPPORT_NAME, mocap=True, pos=[-1.5, -2.0, -0.5])
    common = {"type": "box", "material": "support_mat", "friction": [1.0, 0.01, 0.0005]}
    body.add("geom", name="support_plate", size=[0.06, 0.06, 0.004], condim=4, **common)
    # off the body's origin, so MuJoCo does not compile it as sharing the body's frame (a
    # geom_sameframe geom ignores the geom_pos a task sets per episode)
    lip = {"size": [0.004, 0.06, 0.01], "pos": [0.064, 0.0, 0.006]}
    body.add("geom", name="support_lip", condim=4, **lip, **common)


def build_multi_scene(
    objects: Sequence[ObjectSpec], cameras: Sequence[CameraSpec] = DEFAULT_CAMERAS
) -> mjcf.RootElement:
    """Arena + arm + several free objects and a support stand, for tables with clutter.

    Every object starts parked (:func:`parking_position`), floating there with gravity
    compensated (``body_gravcomp``, which a task sets to 0 when it puts the object on the table),
    so one compiled scene serves every choice of target and distractors among ``objects`` without
    recompiling at reset. The scene knows nothing of targets: which object is which is the
    task's business.
    """
    names = [o.name for o in objects]
    if len(set(names)) != len(names) or not names:
        raise ValueError(f"a multi-object scene needs distinct objects, got {names}")
    cam_names = [c.name for c in cameras]
    if len(set(cam_names)) != len(cam_names):
        raise ValueError(f"camera names must be unique, got {cam_names}")
    arena = _arena(cameras)
    base = arena.worldbody.add("site", name="robot_base", pos=[0, 0, TABLE_HEIGHT], group=5)
    base.attach(build_arm())
    for i, spec in enumerate(objects):
        obj = _object(spec)
        obj.find("body", "object").gravcomp = 1.0  # floats where parked until a task drops it
        frame = arena.worldbody.attach(obj)
        frame.pos = list(parking_position(i))
        frame.add("freejoint", name="free")
    _support(arena)
    return arena
