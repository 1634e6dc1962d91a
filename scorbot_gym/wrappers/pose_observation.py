"""``PoseEstimateObservation``: the pose estimator in the loop, as an observation wrapper.

At reset and then every ``estimate_every`` steps the wrapper hands the step's observation
(camera images) and the cameras' public calibration to a pose source, converts nothing itself
(sources answer in the world frame) and adds to the observation:

- ``object_pos`` (3) and ``object_quat`` (4, w x y z) or ``object_yaw`` (sin, cos): the last
  *valid* estimate, held between estimates and when an estimate fails;
- ``pose_valid`` (1): whether the latest estimate succeeded;
- ``pose_confidence`` (1): the source's confidence in the held estimate, in [0, 1];
- ``pose_age`` (1): steps since the held estimate was made (``MAX_AGE`` before the first);
- ``object_class`` (n, optional): one-hot of the class the source used;
- ``neighbour_points`` (``MAX_NEIGHBOUR_POINTS`` x 3) and ``neighbour_valid`` (its rows in use),
  optional (``neighbours=True``): the other objects on a cluttered table as points on the table
  plane with the height of their tops, from the same source and step as the held estimate
  (:mod:`scorbot_gym.perception.neighbours`: the oracle's from the ground truth, the image
  sources' from the blobs other than the target's), so a controller can keep its fingers off
  them.

``info["perception"]`` carries, at every step, what the estimate was worth against the ground
truth (rotation error, position error, ADD-S, success@5°), the recognised and the true class,
keypoint and inlier counts. These are measured for the record and never enter the observation.

The per-stage wall-clock timings are not in ``info`` by default: they differ between two runs
of the same seed and actions, and ``info`` is part of what a seeded episode reproduces
(Gymnasium's ``check_env`` compares it). They are the wrapper's ``perception_timings``
(``{"total_ms", "timings_ms"}`` of the last step, ``None`` where no estimate ran), as
``RecordEpisodeStatistics`` keeps its wall-clock times in ``time_queue``; ``timings_in_info=True``
adds them to ``info["perception"]`` as well.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.envs.registration import EnvSpec

from pose.camera import CameraModel
from pose.metrics import add_s, rotation_error_deg
from scorbot_gym.envs.arguments import name_list
from scorbot_gym.envs.worker import built_or_failed
from scorbot_gym.names import IDENTITIES
from scorbot_gym.objects import get_object
from scorbot_gym.perception.base import PerceptionFrame, PoseSource, WorldPose
from scorbot_gym.perception.neighbours import MAX_NEIGHBOUR_POINTS, pack_points
from scorbot_gym.perception.references import spec_kwargs
from scorbot_gym.perception.registry import make_pose_source
from scorbot_gym.sim.simulation import quat_to_mat

MAX_AGE = 1000
ROTATION_FORMS = ("quat", "yaw")


class PoseEstimateObservation(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Add a pose source's estimate of the object's pose to the observation.

    Parameters
    ----------
    source
        A registered pose-source name (``"oracle"``, ``"noisy_oracle"``, ``"manifold"``...) or
        a :class:`~scorbot_gym.perception.base.PoseSource`; ``source_kwargs`` go to its factory.
    estimate_every
        Estimate at reset and then every this many steps; ``0`` estimates once, at reset.
    rotation
        ``"quat"`` adds ``object_quat`` (4); ``"yaw"`` adds ``object_yaw`` (sin, cos).
    include_class, classes
        Add ``object_class``, a one-hot over ``classes`` (default: the env's objects).
    identity
        ``"given"``: the source is told the object's true identity (what the user passes;
        recorded as such). ``"recognize"``: it is withheld and the source recognises the
        object from the images; ``info["perception"]["recognised"]`` records its answer next
        to ``true_class``, so wrong recognitions are counted.
    keep_images
        Keep the observation entries the source consumed (camera images); dropped by default,
        so a policy sees only the estimate.
    timings_in_info
        Also put the step's wall-clock timings (``total_ms``, ``timings_ms``) in
        ``info["perception"]``; they are always in :attr:`perception_timings`.
    neighbours
        Add ``neighbour_points`` and ``neighbour_valid``: the source must answer
        ``neighbours(frame)`` (the oracle family and the clutter sources do).
    source_not_recorded
        Set by the env's spec only, where the source's arguments could not be recorded (an
        object other than a model set): re-making from that spec raises this reason.

    The env's spec names the source and its arguments as plain data, a model set by its file
    (:mod:`scorbot_gym.perception.references`), so ``gym.make(env.spec)`` rebuilds the env.
    """

    def __init__(
        self,
        env: gym.Env,
        source: str | PoseSource = "oracle",
        *,
        estimate_every: int = 1,
        rotation: str = "quat",
        include_class: bool = False,
        classes: Sequence[str] | None = None,
        identity: str = "given",
        keep_images: bool = False,
        timings_in_info: bool = False,
        neighbours: bool = False,
        source_not_recorded: str | None = None,
        **source_kwargs: Any,
    ) -> None:
        # The spec records how to rebuild the wrapper (gym.make(env.spec), check_env): these
        # arguments, and the source's name and arguments as plain data, added when the spec is
        # first asked for (a model set by its file: see the spec property).
        if source_not_recorded is not None:
            raise ValueError(
                f"this env spec cannot rebuild its pose source: {source_not_recorded}; make "
                "the env again with make_env(pose=NAME, pose_kwargs=...) of plain values, "
                "model sets or model-file paths"
            )
        gym.utils.RecordConstructorArgs.__init__(
            self,
            estimate_every=estimate_every,
            rotation=rotation,
            include_class=include_class,
            classes=classes,
            identity=identity,
            keep_images=keep_images,
            timings_in_info=timings_in_info,
            neighbours=neighbours,
        )
        self._made_with = (source, source_kwargs)
        gym.Wrapper.__init__(self, env)
        if isinstance(estimate_every, bool) or not isinstance(estimate_every, (int, np.integer)):
            raise ValueError(f"estimate_every must be an int >= 0, got {estimate_every!r}")
        if estimate_every < 0:
            raise ValueError(
                f"estimate_every must be >= 0 (0: once per episode), got {estimate_every}"
            )
        if rotation not in ROTATION_FORMS:
            raise ValueError(f"rotation must be one of {ROTATION_FORMS}, got {rotation!r}")
        if identity not in IDENTITIES:
            raise ValueError(f"identity must be one of {IDENTITIES}, got {identity!r}")
        for flag, value in (
            ("timings_in_info", timings_in_info),
            ("neighbours", neighbours),
            ("include_class", include_class),
            ("keep_images", keep_images),
        ):
            if not isinstance(value, bool):
                raise ValueError(f"{flag} must be True or False, got {value!r}")
        self.timings_in_info = timings_in_info
        #: the last step's wall-clock timings: ``{"total_ms", "timings_ms"}``, or ``None``
        self.perception_timings: dict[str, Any] | None = None
        self.source = make_pose_source(source, **source_kwargs)
        self.source_name = getattr(self.source, "name", None) or type(self.source).__name__
        if neighbours and not callable(getattr(self.source, "neighbours", None)):
            raise ValueError(
                f"neighbours=True needs a pose source that reports the other objects "
                f"(neighbours(frame)); {self.source_name!r} does not"
            )
        self.neighbours = neighbours
        self.estimate_every = int(estimate_every)
        self.rotation, self.include_class, self.identity = rotation, include_class, identity
        self.class_names = (
            name_list("classes", classes, "banana")
            if classes is not None
            else tuple(env.get_wrapper_attr("object_names"))
        )
        if not self.class_names:
            raise ValueError("classes must name at least one catalogue object (None: the env's)")
        for name in self.class_names:
            get_object(name)  # KeyError listing the valid names
        base = env.observation_space
        if not isinstance(base, spaces.Dict):
            raise TypeError("PoseEstimateObservation needs a Dict observation space")
        missing = [k for k in self.source.required_keys if k not in base.spaces]
        if missing:
            raise ValueError(
                f"pose source {self.source_name!r} reads observation entries {missing} that the "
                f"env does not produce (it has {sorted(base.spaces)}); make the env with the "
                "cameras and image types the source needs, e.g. cameras=['top'], "
                "image_width=320, image_height=240"
            )
        self._dropped = () if keep_images else tuple(self.source.required_keys)
        new = {k: v for k, v in base.spaces.items() if k not in self._dropped}
        new["object_pos"] = spaces.Box(-3.0, 3.0, (3,), np.float64)
        if rotation == "quat":
            new["object_quat"] = spaces.Box(-1.0, 1.0, (4,), np.float64)
        else:
            new["object_yaw"] = spaces.Box(-1.0, 1.0, (2,), np.float64)
        new["pose_valid"] = spaces.Box(0.0, 1.0, (1,), np.float64)
        new["pose_confidence"] = spaces.Box(0.0, 1.0, (1,), np.float64)
        new["pose_age"] = spaces.Box(0.0, float(MAX_AGE), (1,), np.float64)
        if include_class:
            new["object_class"] = spaces.Box(0.0, 1.0, (len(self.class_names),), np.float64)
        if neighbours:
            new["neighbour_points"] = spaces.Box(-3.0, 3.0, (MAX_NEIGHBOUR_POINTS, 3), np.float64)
            new["neighbour_valid"] = spaces.Box(0.0, 1.0, (MAX_NEIGHBOUR_POINTS,), np.float64)
        self.observation_space = spaces.Dict(new)
        self._rng = np.random.default_rng()
        self._held: WorldPose | None = None
        self._held_neighbours = pack_points(np.zeros((0, 3)))
        self._age, self._last_valid, self._t = MAX_AGE, False, 0
        self._cameras: dict = {}
        self._backgrounds: dict = {}

    @property
    def spec(self) -> EnvSpec | None:
        """Gymnasium's spec of the wrapped env with this wrapper: its arguments and the pose
        source's, as plain data (a model set by its file; one that lives only in memory is
        written to the cache, by content, when the spec is first asked for), remade by
        :func:`remake_pose_observation` (in a vector-env worker its error reaches the main
        process: a model file deleted since, say)."""
        spec = super().spec
        if spec is None or spec.additional_wrappers[-1].entry_point == _REMAKE:
            return spec
        name, recorded, not_recorded = _recordable_source(*self._made_with)
        last = spec.additional_wrappers[-1]
        kwargs = {"source": name, **last.kwargs, **recorded}
        if not_recorded:
            kwargs["source_not_recorded"] = not_recorded
        last = dataclasses.replace(last, entry_point=_REMAKE, kwargs=kwargs)
        spec.additional_wrappers = (*spec.additional_wrappers[:-1], last)
        return spec

    # --- gym API -----------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        if seed is not None:  # its own stream: the env's draws stay what they are unwrapped
            self._rng = np.random.default_rng([int(seed), 0x5EED])
        self._held, self._age, self._last_valid, self._t = None, MAX_AGE, False, 0
        self._held_neighbours = pack_points(np.zeros((0, 3)))
        self._cameras = {}
        self._backgrounds = dict(info.get("camera_background", {}))
        self._update_cameras(info)
        frame = self._frame(obs, info)
        self.source.reset(frame, self._rng)
        record = self._split_timings(self._estimate(frame, info))
        return self._observation(obs), {**info, "perception": record}

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._t += 1
        self._update_cameras(info)
        due = self.estimate_every > 0 and self._t % self.estimate_every == 0
        if due:
            record = self._estimate(self._frame(obs, info), info)
        else:
            self._age = min(self._age + 1, MAX_AGE)
            record = self._record(info, None)
        record = self._split_timings(record)
        return self._observation(obs), reward, terminated, truncated, {**info, "perception": record}

    # --- internals ---------------------------------------------------------------------------
    def _split_timings(self, record: dict[str, Any]) -> dict[str, Any]:
        """Move the wall-clock timings out of ``record`` into :attr:`perception_timings`."""
        timings = {"total_ms": record.pop("total_ms"), "timings_ms": record.pop("timings_ms")}
        self.perception_timings = timings if record["estimated"] else None
        return {**record, **timings} if self.timings_in_info else record

    def _update_cameras(self, info: dict) -> None:
        """Keep each camera's calibration: from the reset's info, replaced whenever a step's info
        carries it again (an env with a moving camera sends it every step)."""
        for name, params in info.get("camera_params", {}).items():
            self._cameras[name] = CameraModel(**params)

    def _frame(self, obs: dict, info: dict) -> PerceptionFrame:
        truth = None
        if self.source.privileged:  # the target's true pose, and on a cluttered table the others'
            truth = dict(info["object_pose"])
            others = {n: o for n, o in info.get("objects", {}).items() if o["role"] != "target"}
            if others:
                truth["others"] = others
        return PerceptionFrame(
            observation=obs,
            cameras=self._cameras,
            object_name=info["object_name"] if self.identity == "given" else None,
            truth=truth,
            step=self._t,
            backgrounds=self._backgrounds,
        )

    def _estimate(self, frame: PerceptionFrame, info: dict) -> dict[str, Any]:
        est = self.source.estimate(frame)
        ok = bool(
            est.valid and np.isfinite(est.position).all() and np.isfinite(est.quaternion).all()
        )
        self._last_valid = ok
        if ok:
            self._held, self._age = est, 0
            if self.neighbours:  # seen in the same step as the held estimate
                t0 = time.perf_counter()
                self._held_neighbours = pack_points(self.source.neighbours(frame))
                est.timings_ms = {**est.timings_ms, "neighbours": 1e3 * (time.perf_counter() - t0)}
        else:
            self._age = min(self._age + 1, MAX_AGE)
        return self._record(info, est)

    def _record(self, info: dict, est: WorldPose | None) -> dict[str, Any]:
        """What this step's perception was worth, for the record (never for the policy)."""
        true_name = info["object_name"]
        rec: dict[str, Any] = {
            "estimated": est is not None,
            "valid": bool(est is not None and self._last_valid),
            "pose_age": self._age,
            "source": self.source_name,
            "privileged": bool(self.source.privileged),
            "identity": self.identity,
            "true_class": true_name,
            "recognised": None,
            "rot_err_deg": None,
            "pos_err_cm": None,
            "add_s_cm": None,
            "success_5deg": None,
            "n_keypoints": 0,
            "n_inliers": 0,
            "total_ms": None,
            "timings_ms": {},
            "reason": "",
            "camera": None,
        }
        if est is None:
            return rec
        rec.update(
            recognised=est.object_name if self.identity == "recognize" else None,
            n_keypoints=int(est.n_keypoints),
            n_inliers=int(est.n_inliers),
            timings_ms=dict(est.timings_ms),
            total_ms=float(sum(est.timings_ms.get(k, 0.0) for k in _TOP_LEVEL_STAGES)),
            reason=est.reason,
            camera=est.camera,
        )
        if "blobs" in est.details and "objects" in info:  # a cluttered table
            rec.update(_score_blobs(est.details, info, self._cameras.get(est.camera)))
        if rec["valid"]:
            spec = get_object(true_name)
            gt_pos = np.asarray(info["object_pose"]["position"], float)
            gt_R = quat_to_mat(info["object_pose"]["quaternion"])
            R = est.rotation
            rot = rotation_error_deg(R, gt_R, spec.symmetry)
            pts, tree = _model_points(true_name)
            rec.update(
                rot_err_deg=float(rot),
                pos_err_cm=float(100 * np.linalg.norm(est.position - gt_pos)),
                add_s_cm=float(100 * add_s(R, est.position, gt_R, gt_pos, pts, tree)),
                success_5deg=bool(rot <= 5.0),
            )
        return rec

    def _observation(self, obs: dict) -> dict[str, np.ndarray]:
        out = {k: v for k, v in obs.items() if k not in self._dropped}
        held = self._held
        pos = held.position if held is not None else np.zeros(3)
        quat = held.quaternion if held is not None else np.array([1.0, 0.0, 0.0, 0.0])
        out["object_pos"] = np.minimum(np.maximum(np.asarray(pos, np.float64), -3.0), 3.0)
        if self.rotation == "quat":
            out["object_quat"] = np.asarray(quat, np.float64).copy()
        else:
            R = quat_to_mat(quat)
            yaw = np.arctan2(R[1, 0], R[0, 0])
            out["object_yaw"] = np.array([np.sin(yaw), np.cos(yaw)])
        out["pose_valid"] = np.array([1.0 if self._last_valid else 0.0])
        conf = float(held.confidence) if held is not None else 0.0
        out["pose_confidence"] = np.array([min(max(conf, 0.0), 1.0)])
        out["pose_age"] = np.array([float(self._age)])
        if self.include_class:
            onehot = np.zeros(len(self.class_names))
            if held is not None and held.object_name in self.class_names:
                onehot[self.class_names.index(held.object_name)] = 1.0
            out["object_class"] = onehot
        if self.neighbours:
            points, valid = self._held_neighbours
            out["neighbour_points"] = np.clip(points, -3.0, 3.0)
            out["neighbour_valid"] = valid.copy()
        return out


def _score_blobs(details: dict, info: dict, camera: CameraModel | None) -> dict[str, Any]:
    """Each blob's true class (the object whose projected centre is nearest the blob's
    centroid) beside its recognition, and whether the blob taken for the target is it."""
    names = list(info["objects"])
    out: dict[str, Any] = {
        "objects": [],
        "target_recognised": None,
        "n_components": details.get("n_components"),  # blobs before splitting
        "n_blobs": len(details["blobs"]),  # after
        "n_objects": len(info["objects"]),  # on the table (some may be out of view)
    }
    if camera is None or not names:
        return out
    centres = camera.project(np.array([info["objects"][n]["position"] for n in names]))
    for blob in details["blobs"]:
        d = np.linalg.norm(centres - np.asarray(blob["centroid_px"]), axis=1)
        out["objects"].append({**blob, "true_class": names[int(np.argmin(d))]})
    chosen = details.get("chosen")
    if chosen is not None:
        out["target_recognised"] = out["objects"][chosen]["true_class"] == info["object_name"]
    return out


_REMAKE = f"{__name__}:remake_pose_observation"


def remake_pose_observation(env: gym.Env, **kwargs: Any) -> gym.Env:
    """``PoseEstimateObservation(env, **kwargs)``: how ``gym.make(spec)`` rebuilds the wrapper.
    In a Gymnasium vector-env worker a failure is handed back as a stand-in env that raises it
    in the main process (:mod:`scorbot_gym.envs.worker`), not as a broken pipe."""

    def build() -> gym.Env:
        try:
            return PoseEstimateObservation(env, **kwargs)
        except BaseException:
            env.close()
            raise

    return built_or_failed(build)


def _recordable_source(
    source: str | PoseSource, source_kwargs: dict[str, Any]
) -> tuple[str, dict[str, Any], str | None]:
    """The source's registered name, its arguments as spec data, and why it cannot be
    recorded (``None`` where it can)."""
    if isinstance(source, str):
        name, made_with = source, source_kwargs
    elif getattr(source, "made_from", None) is None:  # built by hand, not by make_pose_source
        name = getattr(source, "name", None) or type(source).__name__
        return name, {}, f"it is a {type(source).__name__} object built outside make_pose_source"
    else:
        name, made_with = source.made_from
    recorded, left_out = spec_kwargs(made_with)
    if left_out:
        return name, recorded, f"{name!r} was made with objects as {', '.join(left_out)}"
    return name, recorded, None


# Stages a pose source reports at top level, and the wrapper's "neighbours" (the other objects,
# where asked for); their sum is the perception time of one step.
_TOP_LEVEL_STAGES = (
    "calibrate",
    "segment",
    "recognise",
    "estimate",
    "support",
    "fallback",
    "motion",
    "neighbours",
)

_POINTS: dict[str, tuple[np.ndarray, Any]] = {}


def _model_points(name: str) -> tuple[np.ndarray, Any]:
    """About 500 of the object's mesh vertices, for ADD-S, and their k-d tree (object frame):
    both built once per object, as the wrapper scores every step."""
    if name not in _POINTS:
        from scipy.spatial import cKDTree  # here: scipy costs an oracle-only env ~20 MB

        pts = get_object(name).mesh_vertices()
        pts = pts[:: max(1, len(pts) // 500)]
        _POINTS[name] = (pts, cKDTree(pts))
    return _POINTS[name]
