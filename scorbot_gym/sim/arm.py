"""MJCF model of the SCORBOT-ER Vplus: 5 revolute joints and a two-finger parallel gripper.

Kinematics follow the ER Vplus data sheet: the shoulder axis is 349 mm above the base plate with
a 16 mm radial offset, upper arm and forearm are 221 mm each, and the tool tip (TCP) is 145 mm
beyond the wrist-pitch axis. Shoulder, elbow and wrist pitch are parallel axes, so the tool pitch
in the arm's vertical plane is the sum of those three angles (positive = raising).

Zero configuration: the arm stretched out horizontally along +x, fingers parallel to the table.
The servos are MuJoCo position actuators with velocity damping (``kv``) and motor armature; the
links are gravity-compensated (``gravcomp``) as the real arm's high-ratio gearboxes make it hold
its pose unpowered, so the servos track without the sag a pure P-controller would show.
"""

from __future__ import annotations

import numpy as np

from scorbot_gym import _gl

mjcf = _gl.import_mjcf()  # dm_control with its own renderer off (see _gl)

SHOULDER_HEIGHT = 0.349
SHOULDER_OFFSET = 0.016
UPPER_ARM = 0.221
FOREARM = 0.221
TOOL_LENGTH = 0.145
GRIPPER_MAX_OPENING = 0.075  # between the finger pads, metres

ARM_JOINTS = ("base", "shoulder", "elbow", "wrist_pitch", "wrist_roll")
JOINT_RANGES_DEG = {
    "base": (-155.0, 155.0),
    "shoulder": (-35.0, 130.0),
    "elbow": (-130.0, 130.0),
    "wrist_pitch": (-130.0, 130.0),
    "wrist_roll": (-180.0, 180.0),
}
# Servo gains (N m / rad) and damping (N m s / rad) per joint; gripper gains in N / m.
_KP = {"base": 200.0, "shoulder": 400.0, "elbow": 250.0, "wrist_pitch": 60.0, "wrist_roll": 20.0}
# kv about 1.1x critical damping for the link inertia seen by each joint (armature included).
_KV = {"base": 16.0, "shoulder": 23.0, "elbow": 12.0, "wrist_pitch": 2.0, "wrist_roll": 0.75}
_FORCE = {"base": 40.0, "shoulder": 60.0, "elbow": 40.0, "wrist_pitch": 12.0, "wrist_roll": 5.0}
_ARMATURE = {"base": 0.1, "shoulder": 0.1, "elbow": 0.05, "wrist_pitch": 0.01, "wrist_roll": 0.005}
GRIPPER_FORCE = 25.0  # N per finger at most
# Joint limits as stiff as the finger contacts (MuJoCo's default limit, solref 0.02 s, is softer
# than the fingers' 0.004 s contacts, so the hand folding onto the column pushed the fingers 7 mm
# past their closed stop). Limits stay soft constraints: see ``ScorbotGraspEnv`` for the clip.
_LIMIT_SOLREF = [0.004, 1.0]
_LIMIT_SOLIMP = [0.95, 0.99, 0.001, 0.5, 2.0]

# A tucked pose that keeps the arm out of the top camera's view of the workspace.
HOME_QPOS = np.deg2rad([0.0, 95.0, -115.0, -70.0, 0.0])

_LINK_RGBA = (0.93, 0.93, 0.9, 1.0)
_JOINT_RGBA = (0.2, 0.2, 0.22, 1.0)
_FINGER_RGBA = (0.15, 0.15, 0.15, 1.0)
_PAD_RGBA = (0.35, 0.1, 0.1, 1.0)


def _capsule(body, name: str, start, end, radius: float, mass: float, rgba=_LINK_RGBA) -> None:
    body.add(
        "geom",
        name=name,
        type="capsule",
        fromto=[*start, *end],
        size=[radius],
        mass=mass,
        rgba=rgba,
        **{"class": "link"},
    )


def _revolute(body, name: str, axis) -> None:
    lo, hi = JOINT_RANGES_DEG[name]
    body.add(
        "joint",
        name=name,
        type="hinge",
        axis=axis,
        range=[np.deg2rad(lo), np.deg2rad(hi)],
        armature=_ARMATURE[name],
        damping=0.05 * _KV[name],
        frictionloss=0.01,
        solreflimit=_LIMIT_SOLREF,
        solimplimit=_LIMIT_SOLIMP,
    )


def build_arm() -> mjcf.RootElement:
    """The arm as a self-contained MJCF model whose base sits at its origin."""
    arm = mjcf.RootElement(model="scorbot")
    link = arm.default.add("default", dclass="link")
    link.geom.set_attributes(
        contype=1, conaffinity=1, group=2, condim=3, friction=[0.8, 0.01, 0.001]
    )
    finger = arm.default.add("default", dclass="finger")
    finger.geom.set_attributes(
        contype=1,
        conaffinity=1,
        group=2,
        condim=4,
        friction=[1.5, 0.02, 0.002],
        solref=[0.004, 1.0],
        solimp=[0.95, 0.99, 0.001, 0.5, 2.0],
        priority=1,
    )

    wb = arm.worldbody
    wb.add(
        "geom",
        name="base_plate",
        type="cylinder",
        size=[0.11, 0.01],
        pos=[0, 0, 0.01],
        rgba=_JOINT_RGBA,
        mass=4.0,
        **{"class": "link"},
    )

    link1 = wb.add("body", name="link1", pos=[0, 0, 0.02], gravcomp=1)
    _revolute(link1, "base", [0, 0, 1])
    link1.add(
        "geom",
        name="column",
        type="cylinder",
        size=[0.075, 0.13],
        pos=[0, 0, 0.13],
        rgba=_LINK_RGBA,
        mass=3.0,
        **{"class": "link"},
    )
    _capsule(
        link1,
        "shoulder_housing",
        [SHOULDER_OFFSET, -0.07, SHOULDER_HEIGHT - 0.02],
        [SHOULDER_OFFSET, 0.07, SHOULDER_HEIGHT - 0.02],
        0.055,
        1.5,
        _JOINT_RGBA,
    )

    upper = link1.add(
        "body", name="upper_arm", pos=[SHOULDER_OFFSET, 0, SHOULDER_HEIGHT - 0.02], gravcomp=1
    )
    _revolute(upper, "shoulder", [0, -1, 0])
    _capsule(upper, "upper_arm_geom", [0.03, 0, 0], [UPPER_ARM - 0.03, 0, 0], 0.035, 1.2)

    fore = upper.add("body", name="forearm", pos=[UPPER_ARM, 0, 0], gravcomp=1)
    _revolute(fore, "elbow", [0, -1, 0])
    _capsule(fore, "elbow_housing", [0, -0.04, 0], [0, 0.04, 0], 0.04, 0.3, _JOINT_RGBA)
    _capsule(fore, "forearm_geom", [0.03, 0, 0], [FOREARM - 0.03, 0, 0], 0.028, 0.9)

    wrist = fore.add("body", name="wrist", pos=[FOREARM, 0, 0], gravcomp=1)
    _revolute(wrist, "wrist_pitch", [0, -1, 0])
    _capsule(wrist, "wrist_housing", [0, -0.03, 0], [0, 0.03, 0], 0.03, 0.25, _JOINT_RGBA)

    hand = wrist.add("body", name="hand", pos=[0.045, 0, 0], gravcomp=1)
    _revolute(hand, "wrist_roll", [1, 0, 0])
    hand.add(
        "geom",
        name="palm",
        type="box",
        size=[0.02, 0.05, 0.022],
        pos=[0.02, 0, 0],
        rgba=_JOINT_RGBA,
        mass=0.3,
        **{"class": "link"},
    )
    # The TCP: midway between the finger pads, 5 mm short of the finger tips.
    hand.add(
        "site",
        name="tcp",
        pos=[TOOL_LENGTH - 0.045, 0, 0],
        size=[0.004],
        rgba=[1, 0, 0, 0.6],
        group=4,
    )
    hand.add(
        "camera", name="eye_in_hand", pos=[0.01, 0, 0.045], fovy=70, xyaxes=[0, -1, 0, 0, 0, 1]
    )

    half = GRIPPER_MAX_OPENING / 2
    for side, sign in (("left", 1), ("right", -1)):
        f = hand.add("body", name=f"finger_{side}", pos=[0.04, 0, 0], gravcomp=1)
        f.add(
            "joint",
            name=f"finger_{side}",
            type="slide",
            axis=[0, sign, 0],
            range=[0, half],
            armature=0.01,
            damping=2.0,
            solreflimit=_LIMIT_SOLREF,
            solimplimit=_LIMIT_SOLIMP,
        )
        # Finger body at the closed position; pads face the centre plane y=0.
        f.add(
            "geom",
            name=f"finger_{side}_link",
            type="box",
            size=[0.032, 0.006, 0.012],
            pos=[0.032, sign * 0.007, 0],
            rgba=_FINGER_RGBA,
            mass=0.05,
            **{"class": "finger"},
        )
        f.add(
            "geom",
            name=f"finger_{side}_pad",
            type="box",
            size=[0.027, 0.0015, 0.011],
            pos=[0.037, sign * 0.0015, 0],
            rgba=_PAD_RGBA,
            mass=0.01,
            **{"class": "finger"},
        )

    arm.equality.add(
        "joint",
        name="finger_coupling",
        joint1="finger_left",
        joint2="finger_right",
        polycoef=[0, 1, 0, 0, 0],
        solref=[0.005, 1],
    )
    opening = arm.tendon.add("fixed", name="gripper_opening")
    opening.add("joint", joint="finger_left", coef=1.0)
    opening.add("joint", joint="finger_right", coef=1.0)

    for name in ARM_JOINTS:
        arm.actuator.add(
            "position",
            name=name,
            joint=name,
            kp=_KP[name],
            kv=_KV[name],
            ctrlrange=np.deg2rad(JOINT_RANGES_DEG[name]),
            forcerange=[-_FORCE[name], _FORCE[name]],
        )
    arm.actuator.add(
        "position",
        name="gripper",
        tendon="gripper_opening",
        kp=800.0,
        kv=40.0,
        ctrlrange=[0, GRIPPER_MAX_OPENING],
        forcerange=[-GRIPPER_FORCE, GRIPPER_FORCE],
    )
    for a, b in (
        ("link1", "upper_arm"),
        ("upper_arm", "forearm"),
        ("forearm", "wrist"),
        ("wrist", "hand"),
        ("finger_left", "finger_right"),
    ):
        arm.contact.add("exclude", body1=a, body2=b)
    return arm
