"""Scripted top-down grasp: approach above, align the wrist, descend, close, lift.

The controller is model-based: it takes the object's pose (position + yaw, from the oracle or an
estimator) and the catalogue model (where and along which direction the object is narrowest), and
tracks straight Cartesian waypoints with the arm's inverse kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scorbot_gym.objects import ObjectSpec
from scorbot_gym.robot import Robot

TOOL_DOWN = -np.pi / 2
PHASES = ("approach", "descend", "close", "lift", "hold")


@dataclass(frozen=True)
class ObjectPose2D:
    """What the controller needs: object position (world, metres) and heading about z."""

    position: np.ndarray
    yaw: float


class ScriptedGraspController:
    """Produces actions for ``ScorbotGraspEnv`` in either action space."""

    def __init__(
        self,
        robot: Robot,
        action_type: str = "joint",
        dt: float = 0.04,
        max_joint_step: float = 0.1,
        max_cartesian_step: float = 0.02,
        max_angle_step: float = 0.1,
        speed: float = 0.3,
        descend_speed: float = 0.12,
        approach_height: float = 0.10,
        lift_height: float = 0.12,
        close_time: float = 0.5,
    ) -> None:
        if action_type not in ("joint", "cartesian"):
            raise ValueError(f"action_type must be 'joint' or 'cartesian', got {action_type!r}")
        self.robot, self.action_type, self.dt = robot, action_type, dt
        self.max_joint_step, self.max_cartesian_step = max_joint_step, max_cartesian_step
        self.max_angle_step = max_angle_step
        self.speed, self.descend_speed = speed, descend_speed
        self.approach_height, self.lift_height, self.close_time = (
            approach_height,
            lift_height,
            close_time,
        )
        self.phase = "approach"

    @classmethod
    def for_env(cls, env, **kwargs) -> ScriptedGraspController:
        """A controller matched to an env's action space and control rate."""
        u = env.unwrapped
        return cls(
            u.robot,
            u.action_type,
            u.dt,
            u.max_joint_step,
            u.max_cartesian_step,
            u.max_angle_step,
            **kwargs,
        )

    def reset(self, pose: ObjectPose2D, spec: ObjectSpec, table_height: float) -> None:
        model = spec.model
        c, s = np.cos(pose.yaw), np.sin(pose.yaw)
        gx, gy = np.asarray(pose.position[:2]) + np.array([[c, -s], [s, c]]) @ model.grasp_point
        top = pose.position[2] + model.half_extents[2]
        # Fingers reach 55 mm below the palm: grasp at mid-height, but low enough for a firm hold
        # and high enough that the palm clears the top.
        z = max(pose.position[2], top - 0.05, table_height + 0.012)
        self.grasp = np.array([gx, gy, z])
        self.closing_yaw = pose.yaw + model.grasp_yaw
        self.phase = "approach"
        self._phase_time = 0.0
        self._waypoint: np.ndarray | None = None  # starts where the TCP is at the first act()

    def _goal(self) -> tuple[np.ndarray, float]:
        g = self.grasp
        if self.phase == "approach":
            return g + [0.0, 0.0, self.approach_height], self.speed
        if self.phase in ("descend", "close"):
            return g, self.descend_speed
        return g + [0.0, 0.0, self.lift_height], self.descend_speed

    def _advance_phase(self, tcp: np.ndarray, goal: np.ndarray) -> None:
        self._phase_time += self.dt
        at_goal = np.allclose(self._waypoint, goal) and np.linalg.norm(tcp - goal) < 0.008
        if self.phase == "approach" and at_goal:
            self.phase, self._phase_time = "descend", 0.0
        elif self.phase == "descend" and (at_goal or self._phase_time > 2.0):
            self.phase, self._phase_time = "close", 0.0
        elif self.phase == "close" and self._phase_time >= self.close_time:
            self.phase, self._phase_time = "lift", 0.0
        elif self.phase == "lift" and at_goal:
            self.phase = "hold"

    def act(self, obs: dict) -> np.ndarray:
        q = np.asarray(obs["joint_pos"], dtype=float)
        tcp = np.asarray(obs["ee_pos"], dtype=float)
        if self._waypoint is None:
            self._waypoint = tcp.copy()
        goal, speed = self._goal()
        # Move the waypoint toward the goal at a bounded speed: straight Cartesian segments.
        delta = goal - self._waypoint
        dist = np.linalg.norm(delta)
        step = speed * self.dt
        self._waypoint = goal.copy() if dist <= step else self._waypoint + delta * (step / dist)
        self._advance_phase(tcp, goal)

        q_goal, _ = self.robot.ik(self._waypoint, TOOL_DOWN, q)
        q_goal[4] = self.robot.roll_for_closing_yaw(q_goal, self.closing_yaw)
        gripper = 1.0 if self.phase in ("approach", "descend") else -1.0
        if self.action_type == "joint":
            arm = (q_goal - q) / self.max_joint_step
        else:
            arm = np.r_[
                (self._waypoint - tcp) / self.max_cartesian_step,
                (TOOL_DOWN - self.robot.tool_pitch(q)) / self.max_angle_step,
                (q_goal[4] - q[4]) / self.max_angle_step,
            ]
        return np.clip(np.r_[arm, gripper], -1.0, 1.0).astype(np.float32)
