"""Pose from a camera image with trained per-object models (``manifold`` and its baselines).

The source segments the object in its camera's image, takes the object's identity (given, or
recognised), runs that object's estimator from a :class:`pose.model_set.PoseModelSet` and
converts the camera-frame answer to the world frame with the camera's public calibration.

Recognition (when the wrapper withholds the identity, ``identity="recognize"``) uses a
recogniser by name (:mod:`scorbot_gym.perception.recognizers`: ``"flr"`` on the silhouettes of
all ``cameras``, fused; ``"appearance"``: the model explaining the most inliers;
``"flr+appearance"``: appearance deciding among FLR's three best) under a
:class:`pose.recognition.RecognitionMemory`: the first confident answer from a clear view is
kept for the episode, since the arm hides the object later in a grasp.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Sequence
from numbers import Real
from typing import Any

import numpy as np

from pose.model_set import PoseModelSet
from pose.recognition import Recognition, RecognitionMemory, view_is_clear
from pose.view import View
from scorbot_gym.names import RECOGNIZERS
from scorbot_gym.perception.base import PerceptionFrame, WorldPose
from scorbot_gym.perception.calibration import (
    ArmCalibration,
    default_calibration,
    make_calibration,
)
from scorbot_gym.perception.motion import SilhouetteMotion, make_motion
from scorbot_gym.perception.recognizers import (
    DEFAULT_RECOGNIZER,
    IdentityOnlyRecognizer,
    make_recognizer,
)
from scorbot_gym.perception.references import load_model_set
from scorbot_gym.perception.segmenters import Segmenter, make_segmenter
from scorbot_gym.perception.support import (
    DEFAULT_SUPPORT,
    TableSupport,
    TableSupportMemory,
    hull_points,
    make_support,
    refine_pose,
    reset_support,
)
from scorbot_gym.sim.simulation import mat_to_quat

_MOVED = "moved"  # the start of the reason of an answer from the motion detector


class ModelSetPoseSource:
    """Estimate the pose with a trained :class:`PoseModelSet` on one camera's images.

    ``models`` is a model set or the path of a file from ``scorbot-gym pose train``; its
    ``meta`` names the camera and image size it was trained for, and the env must render that
    camera at that size (``cameras=[camera], image_width=..., image_height=...``).

    Parameters
    ----------
    segmenter
        ``"background"`` (default: background subtraction minus the arm, no simulator),
        ``"privileged"`` (the simulator's own mask, for oracle and ablation runs) or a
        segmenter object.
    cameras
        Cameras to use; the pose comes from the model set's camera (added first if missing),
        the others serve recognition (e.g. ``("top", "side")``).
    recognizer
        Used only when the identity is withheld: ``"appearance"`` (default: the class whose
        pose model explains the most keypoints), ``"flr+appearance"`` (FLR's three best
        classes, decided by appearance; the default until 2026-11-27), ``"flr"`` or an object with
        ``recognize`` (taking ``{camera: mask}`` if its ``reads`` is ``"silhouettes"``, both
        if ``"silhouettes+view"``, else a :class:`pose.view.View`); built on the first reset
        that needs it.
    memory
        When to keep a recognition (default :class:`RecognitionMemory`: first clear view).
    clear_min_area
        Pixels a silhouette needs (in every camera used) for its view to count as clear.
    fallback_models
        Model sets (or files) of other cameras at the same image size, tried in order where
        the primary camera's estimate is invalid: during a grasp the arm hides the object from
        above, while a side camera still sees it.
    motion
        Where no camera gives a valid estimate: ``"silhouette"`` (a
        :class:`~scorbot_gym.perception.motion.SilhouetteMotion`, or one with other
        parameters) answers the object's new position and heading if a clear silhouette in one
        of the cameras shows that it moved since the last valid estimate (``reason`` says so);
        ``None`` (default) answers invalid.
    support
        ``"table_memory"`` (default: a
        :class:`~scorbot_gym.perception.support.TableSupportMemory`, whether the object rests
        on the table is decided on the first clear views and held for the episode, and every
        estimate of a resting one is put on the table), ``"table"`` (a
        :class:`~scorbot_gym.perception.support.TableSupport`: each estimate within a few
        degrees of a resting pose is put on the table; the default until 2026-11-27),
        ``"none"`` (estimates as the models answer them) or a support object with
        ``refine(pose, camera)``.
    recognition_models
        Where ``models`` hold a baseline (the image-blind ``chance`` arm): the trained model
        set (or file) whose ``recognizer`` names the object, its pose estimates dropped
        (:class:`~scorbot_gym.perception.recognizers.IdentityOnlyRecognizer`), so that only
        the estimator differs between the arms. By file or set, never as a built recogniser,
        so the env's spec can rebuild the source.
    resting_models
        A second model set (or file) of the same camera, image size and objects, trained on
        resting views only: the resting hypothesis. Where the primary models' estimate is
        within a few degrees of one of the object's resting poses
        (:meth:`TableSupport.is_resting`), the resting models' estimate on the same view
        replaces it if valid: models trained on 3-D tilts (the default ``models``) answer the
        height along the top camera's line of sight worse than models that only know the
        object lying on the table, which lose thin objects (marker, banana) less often; objects
        the primary models find tilted keep their estimate. ``None`` (default): the primary
        models alone.
    calibration
        ``"arm"`` (an :class:`~scorbot_gym.perception.calibration.ArmCalibration`: each
        fixed pose camera re-calibrated at every estimate from the arm's silhouette, which
        cancels an error of the cameras' calibration; needs the ``"background"`` segmenter;
        while the arm hides the object, the last estimate is answered again through the
        camera as re-calibrated), ``"none"`` (every camera as its public calibration says),
        or such an object; ``None`` (default):
        :data:`~scorbot_gym.perception.calibration.DEFAULT_CALIBRATION` where the segmenter
        can show the arm, else ``"none"``.
    """

    def __init__(
        self,
        models: PoseModelSet | str | os.PathLike,
        segmenter: Segmenter | str = "background",
        cameras: Sequence[str] | None = None,
        recognizer: str | Any = DEFAULT_RECOGNIZER,
        memory: RecognitionMemory | None = None,
        clear_min_area: int = 200,
        fallback_models: Sequence[PoseModelSet | str | os.PathLike] = (),
        motion: str | SilhouetteMotion | None = None,
        support: TableSupport | TableSupportMemory | str | None = DEFAULT_SUPPORT,
        recognition_models: PoseModelSet | str | os.PathLike | None = None,
        resting_models: PoseModelSet | str | os.PathLike | None = None,
        calibration: str | ArmCalibration | None = None,
    ) -> None:
        self.models = _load(models)
        self.resting_models = None if resting_models is None else _load(resting_models)
        if self.resting_models is not None:
            self._check_resting(self.resting_models)
        self.recognition_models = None
        if recognition_models is not None:
            self.recognition_models = _load(recognition_models)
            if self.recognition_models.object_names != self.models.object_names:
                raise ValueError(
                    f"recognition_models must hold the objects of models "
                    f"{self.models.object_names}, got {self.recognition_models.object_names}"
                )
        self.support = make_support(support)
        meta = self.models.meta
        self.camera = str(meta.get("camera", "top"))
        self.width, self.height = int(meta.get("width", 640)), int(meta.get("height", 480))
        self.fallback_models = tuple(_load(m) for m in fallback_models)
        for fb in self.fallback_models:
            size = (int(fb.meta.get("width", 640)), int(fb.meta.get("height", 480)))
            if size != (self.width, self.height) or fb.meta.get("camera") in (None, self.camera):
                raise ValueError(
                    "fallback_models must be model sets of other cameras at the primary's image "
                    f"size {self.width}x{self.height}, got camera {fb.meta.get('camera')!r} at "
                    f"{size[0]}x{size[1]}"
                )
        self.segmenter = make_segmenter(segmenter)
        if calibration is None:
            calibration = default_calibration(self.segmenter)
        self.calibration = make_calibration(calibration)
        if isinstance(self.calibration, ArmCalibration):
            ArmCalibration.check_segmenter(self.segmenter)
        if isinstance(cameras, str):
            raise ValueError(f"cameras must be a list of camera names, got the string {cameras!r}")
        extra = [c for c in (cameras or ()) if c != self.camera]
        extra += [str(fb.meta["camera"]) for fb in self.fallback_models]
        self.cameras = (self.camera, *dict.fromkeys(extra))
        check_recognizer(recognizer)
        self.recognizer = recognizer
        self.memory = memory if memory is not None else RecognitionMemory()
        self.clear_min_area = int(non_negative("clear_min_area", clear_min_area))
        self._recognizer: Any = None
        self.motion = make_motion(motion)
        self._last: WorldPose | None = None  # the last valid answer, for ``motion``
        #: the last valid estimate before the support prior, with its camera as calibrated then
        self._seen: tuple[WorldPose, Any] | None = None
        self._masks: dict[str, np.ndarray | None] = {}  # this step's masks, by camera

    def _check_resting(self, resting: PoseModelSet) -> None:
        """``resting_models`` must answer the primary models' camera, size and objects."""
        keys = ("camera", "width", "height")
        theirs = {k: resting.meta.get(k) for k in keys}
        ours = {k: self.models.meta.get(k) for k in keys}
        if theirs != ours or resting.object_names != self.models.object_names:
            raise ValueError(
                f"resting_models must be a model set of the primary models' camera, image size "
                f"and objects ({ours}, {len(self.models.object_names)} objects), got {theirs} "
                f"with {len(resting.object_names)} objects"
            )

    @property
    def privileged(self) -> bool:
        return self.segmenter.privileged

    @property
    def required_keys(self) -> tuple[str, ...]:
        keys: list[str] = []
        for cam in self.cameras:
            keys += [f"{cam}_rgb", *self.segmenter.required_keys(cam)]
        return tuple(keys)

    @property
    def env_requirements(self) -> dict:
        """The env keyword arguments that make it render what this source reads."""
        return {
            "cameras": list(self.cameras),
            "image_width": self.width,
            "image_height": self.height,
            "image_types": ["rgb", *self.segmenter.image_types],
            **getattr(self.segmenter, "env_kwargs", {}),
        }

    def reset(self, frame: PerceptionFrame, rng: np.random.Generator) -> None:
        self._last = self._seen = None
        self._masks = {}
        for cam in self.cameras:
            self.segmenter.reset(frame, cam)
        if self.calibration is not None:
            pose_cameras = (self.camera, *(str(fb.meta["camera"]) for fb in self.fallback_models))
            self.calibration.reset(frame, pose_cameras, self.segmenter)
        self.memory.reset()
        reset_support(self.support)
        if frame.object_name is None and len(self.models.object_names) > 1:
            if self._recognizer is None:
                recognising = self.recognition_models or self.models
                self._recognizer = make_recognizer(
                    self.recognizer, recognising, self.cameras, self.width, self.height
                )
                if self.recognition_models is not None:  # its label, not its pose estimates
                    self._recognizer = IdentityOnlyRecognizer(self._recognizer)

    def _clear(self, mask: np.ndarray | None, cam: str) -> bool:
        excluded = getattr(self.segmenter, "excluded", lambda c: None)(cam)
        return view_is_clear(mask, excluded, min_area=self.clear_min_area)

    def _recognise(self, frame: PerceptionFrame, view: View) -> Recognition | None:
        """This step's recognition (``None`` when a kept one makes it unnecessary)."""
        if self.memory.kept is not None:
            return None
        rec = self._recognizer
        reads = getattr(rec, "reads", "view")
        if reads in ("silhouettes", "silhouettes+view"):  # masks of all cameras
            masks = {self.camera: view.mask}
            for cam in self.cameras[1:]:
                masks[cam] = self.segmenter.segment(frame, cam)
            result = rec.recognize(masks) if reads == "silhouettes" else rec.recognize(masks, view)
            clear = all(self._clear(masks[c], c) for c in masks)
        else:
            result = rec.recognize(view)
            clear = self._clear(view.mask, self.camera)
        self.memory.offer(result, clear)
        return result

    def estimate(self, frame: PerceptionFrame) -> WorldPose:
        """The primary camera's estimate; where it is invalid (e.g. the arm hides the object
        from above), the first valid one of the fallback cameras, for the same object."""
        self._masks = {}
        calibrate_ms = None
        if self.calibration is not None:
            t0 = time.perf_counter()
            at = None if self._last is None else self._last.position
            frame = self.calibration.update(frame, self.segmenter, at)
            calibrate_ms = (time.perf_counter() - t0) * 1e3
        seen = self._estimate_primary(frame)
        pose = self._supported(seen, frame)
        if calibrate_ms is not None:
            pose.timings_ms = {"calibrate": calibrate_ms, **pose.timings_ms}
        if not (pose.valid or pose.object_name is None):
            timings = dict(pose.timings_ms)  # shared: fallbacks' times add up under "fallback"
            for models in self.fallback_models:
                alt = self._estimate_with(models, frame, pose.object_name, timings)
                if alt.valid:
                    seen, pose = alt, self._supported(alt, frame)
                    break
            else:
                pose = dataclasses.replace(pose, timings_ms=timings)
                if self.motion is not None:
                    t0 = time.perf_counter()
                    moved = self._moved(frame, pose)
                    timings["motion"] = (time.perf_counter() - t0) * 1e3
                    pose = moved or pose
                if self.calibration is not None and not pose.valid:
                    pose = self._recalibrated(frame, pose) or pose
        if seen.valid:  # what a camera saw, and how it was calibrated then
            self._seen = (seen, frame.cameras[seen.camera])
        if pose.valid:
            self._last = pose
        return pose

    def _recalibrated(self, frame: PerceptionFrame, invalid: WorldPose) -> WorldPose | None:
        """The last estimate, seen through its camera as calibrated now, where the calibration
        has moved it since (by over a millimetre): while the arm hides the object, the plan
        would otherwise keep an estimate placed through a calibration the arm's silhouette
        has since corrected."""
        if self._seen is None or self._last is None:
            return None
        seen, camera_then = self._seen
        if seen.object_name != invalid.object_name:
            return None
        now = np.asarray(frame.cameras[seen.camera].world_from_camera, float)
        M = now @ np.linalg.inv(np.asarray(camera_then.world_from_camera, float))
        position = M[:3, :3] @ seen.position + M[:3, 3]
        if np.linalg.norm(position - seen.position) < 1e-3:  # not worth a new answer
            return None
        pose = dataclasses.replace(
            seen,
            position=position,
            quaternion=mat_to_quat(M[:3, :3] @ seen.rotation),
            n_keypoints=0,
            n_inliers=0,
            timings_ms=invalid.timings_ms,
            reason="re-calibrated: the last estimate through the camera as calibrated now",
        )
        return self._supported(pose, frame)

    def _supported(self, pose: WorldPose, frame: PerceptionFrame) -> WorldPose:
        """``pose`` refined by the support prior (if any) with its camera's calibration."""
        if self.support is None or not pose.valid:
            return pose
        cam = pose.camera
        clear = lambda: self._clear(self._masks.get(cam), cam)  # noqa: E731  (asked only if needed)
        return refine_pose(self.support, pose, frame.cameras[cam], clear)

    def _moved(self, frame: PerceptionFrame, invalid: WorldPose) -> WorldPose | None:
        """The last valid pose, moved to where a clear silhouette now places the object; or,
        after such a move, the moved pose again while silhouettes agree with it (the
        controller's filter takes a lone jump for noise until later estimates confirm it)."""
        last = self._last
        if last is None or last.object_name != invalid.object_name:
            return None
        excluded = getattr(self.segmenter, "excluded", lambda c: None)
        points = hull_points(last.object_name)
        for cam in self.cameras:
            if cam not in self._masks:  # not segmented on the way here (a recognition camera)
                self._masks[cam] = self.segmenter.segment(frame, cam)
            found = self.motion.locate(
                self._masks[cam],
                excluded(cam),
                frame.cameras[cam],
                last.position,
                last.rotation,
                points,
            )
            if found is None:
                continue
            common = dict(n_keypoints=0, n_inliers=0, timings_ms=invalid.timings_ms, camera=cam)
            if self.motion.is_move(found[0], last.position):
                return dataclasses.replace(
                    last,
                    position=found[0],
                    quaternion=mat_to_quat(found[1]),
                    confidence=0.5 * last.confidence,
                    reason=f"{_MOVED}: position and heading from the silhouette",
                    **common,
                )
            if last.reason.startswith(_MOVED):
                return dataclasses.replace(
                    last, reason=f"{_MOVED}: confirmed by the silhouette", **common
                )
        return None

    def _estimate_with(
        self, models: PoseModelSet, frame: PerceptionFrame, name: str, timings: dict
    ) -> WorldPose:
        cam_name = str(models.meta["camera"])
        t0 = time.perf_counter()
        mask = self.segmenter.segment(frame, cam_name)
        self._masks[cam_name] = mask
        t1 = time.perf_counter()
        timings[f"segment_{cam_name}"] = (t1 - t0) * 1e3
        est = None
        if mask is not None:
            cam = frame.cameras[cam_name]
            view = View(np.asarray(frame.observation[f"{cam_name}_rgb"]), cam, mask, name)
            est = models.predict(view)
            timings[f"estimate_{cam_name}"] = (time.perf_counter() - t1) * 1e3
        timings["fallback"] = timings.get("fallback", 0.0) + (time.perf_counter() - t0) * 1e3
        if est is None:
            return WorldPose.invalid("no object in view", object_name=name, timings_ms=timings)
        return _world_pose(est, cam, name, timings, cam_name)

    def _estimate_primary(self, frame: PerceptionFrame) -> WorldPose:
        cam_name = self.camera
        t0 = time.perf_counter()
        mask = self.segmenter.segment(frame, cam_name)
        self._masks[cam_name] = mask
        timings = {"segment": (time.perf_counter() - t0) * 1e3}
        timings.update(
            {f"segment_{k}": v for k, v in getattr(self.segmenter, "timings_ms", {}).items()}
        )
        name = frame.object_name
        if name is None and len(self.models.object_names) == 1:
            name = self.models.object_names[0]
        if mask is None:
            return WorldPose.invalid(
                "no object in view",
                object_name=name or self.memory.label_for(None),
                timings_ms=timings,
            )
        cam = frame.cameras[cam_name]
        image = np.asarray(frame.observation[f"{cam_name}_rgb"])
        view = View(image, cam, mask, name)
        result = None
        if name is None:
            if self._recognizer is None:
                raise ValueError(
                    "ModelSetPoseSource needs the object's identity (frame.object_name) or a "
                    f"reset without one to set up recognition ({self.models.object_names})"
                )
            t0 = time.perf_counter()
            result = self._recognise(frame, view)
            timings["recognise"] = (time.perf_counter() - t0) * 1e3
            name = self.memory.label_for(result)
            if name is None:
                return WorldPose.invalid("object not recognised", timings_ms=timings)
            view = View(image, cam, mask, name)
        if result is not None and name in result.estimates:  # timed under "recognise"
            est = result.estimates[name]
            timings["estimate"] = 0.0
        else:
            est = self.models.predict(view)
            timings.update({f"estimate_{k}": v for k, v in est.timings_ms.items() if k != "total"})
            timings["estimate"] = est.timings_ms.get("total", 0.0)
        return self._resting_hypothesis(_world_pose(est, cam, name, timings, cam_name), view)

    def _resting_hypothesis(self, pose: WorldPose, view: View) -> WorldPose:
        """``pose``, or where it is near a resting pose the ``resting_models``' valid estimate
        on the same view (``details["hypothesis"]`` says which was kept)."""
        if self.resting_models is None or not self._resting_check.is_resting(pose):
            return pose
        t0 = time.perf_counter()
        est = self.resting_models.predict(view)
        timings = {**pose.timings_ms, "estimate_resting": (time.perf_counter() - t0) * 1e3}
        if not est.valid:
            return dataclasses.replace(
                pose, timings_ms=timings, details={**pose.details, "hypothesis": "primary"}
            )
        alt = _world_pose(est, view.camera, pose.object_name, timings, self.camera)
        return dataclasses.replace(alt, details={**alt.details, "hypothesis": "resting"})

    @property
    def _resting_check(self) -> TableSupport:
        """The table-top prior's resting test (the source's own prior if it is one)."""
        return self.support if isinstance(self.support, TableSupport) else TableSupport()


def _load(models: PoseModelSet | str | os.PathLike) -> PoseModelSet:
    if isinstance(models, PoseModelSet):
        return models
    if not isinstance(models, (str, os.PathLike)):
        raise ValueError(
            f"models must be a PoseModelSet or the path of a model file from `scorbot-gym pose "
            f"train`, got {type(models).__name__} {models!r}"
        )
    return load_model_set(models)  # remembered as that file's: the env's spec names it


def check_recognizer(recognizer: Any) -> None:
    """A recogniser name must be one of :data:`RECOGNIZERS` (checked when the source is made,
    not at the first reset that recognises), or an object with ``recognize``."""
    if isinstance(recognizer, str) and recognizer not in RECOGNIZERS:
        raise ValueError(f"unknown recognizer {recognizer!r}; valid: {', '.join(RECOGNIZERS)}")


def non_negative(name: str, value: Any) -> float:
    """A number >= 0 (a pixel count, a distance), or a one-line error naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, Real) or not 0 <= value < float("inf"):
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return value


def _world_pose(est: Any, cam: Any, name: str, timings: dict, cam_name: str) -> WorldPose:
    """A camera-frame estimate in the world frame, through the camera's public extrinsics."""
    common = dict(
        object_name=name,
        n_keypoints=est.n_keypoints,
        n_inliers=est.n_inliers,
        timings_ms=timings,
        camera=cam_name,
    )
    if not est.valid:
        return WorldPose.invalid(est.reason, **common)
    T = cam.world_from_camera
    R_world = T[:3, :3] @ est.rotation
    t_world = T[:3, :3] @ est.translation + T[:3, 3]
    return WorldPose(t_world, mat_to_quat(R_world), True, est.confidence, **common)
