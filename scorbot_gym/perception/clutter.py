"""The target's pose on a table with several objects (pose source ``manifold_clutter``).

Background subtraction on a cluttered table changes many pixels: one blob per object, or one
for objects that touch in the image. The single-object source takes the largest blob, which is
as often a distractor as the target. This source splits the foreground (minus the arm, rendered
from its model) into connected components, recognises each (FLR shortlist + appearance, as the
single-object source does, on that blob's silhouette and pixels), and estimates the pose of the
**target** (the task command, ``frame.object_name``) on the blob recognised as it. Where no
blob is recognised as the target, the blob on which the target's model explains the most
RANSAC inliers is taken (keypoint-to-model assignment; before the target is first found this
includes blobs recognised as another object: objects touching in the image share a blob).
Once a valid estimate exists the target's blob is followed from step to step (the blob
nearest the last estimate's projection, within a gate), so the full recognition runs only when
the target is lost: during the grasp the arm splits and hides blobs, and recognising every blob
at every step would cost one estimate per class. For the same reason a blob at about the place
and size of one recognised earlier in the episode keeps that label.

Blobs that several objects share can be split before recognition (``splitter``, a component
of :mod:`scorbot_gym.perception.splitters`: ``"keypoints"`` assigns each blob's keypoints to
the models that explain them and splits its pixels by a watershed seeded with them; the
default ``"none"`` leaves blobs whole), so that each object is recognised, and the target's
pose estimated, on its own pixels. ``details`` then counts the blobs before and after.

A wrong pick is counted, never hidden: ``details["blobs"]`` lists every blob's recognition
(``PoseEstimateObservation`` scores them against the ground truth in ``info["perception"]``).
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from pose.model_set import PoseModelSet
from pose.recognition import view_is_clear
from pose.segmentation import BackgroundSubtractionSegmenter, components
from pose.view import View
from scorbot_gym.perception.base import PerceptionFrame, WorldPose
from scorbot_gym.perception.model_set import _load, _world_pose, check_recognizer, non_negative
from scorbot_gym.perception.recognizers import make_recognizer
from scorbot_gym.perception.segmenters import BackgroundSegmenter
from scorbot_gym.perception.splitters import make_splitter
from scorbot_gym.perception.support import (
    TableSupport,
    TableSupportMemory,
    make_support,
    refine_pose,
    reset_support,
)

#: pixels (at 320 x 240) a blob needs to count as an object
MIN_BLOB_AREA = 120
#: how far (pixels) the target's blob may be from the last estimate's projection to be followed
TRACK_GATE_PX = 25.0
#: pixels the target's projected outline is grown by before the rest of its blob is a neighbour
OUTLINE_GROW_PX = 3


class BlobSegmenter(BackgroundSegmenter):
    """Background subtraction minus the arm, split into blobs (largest first).

    ``segment`` stays the largest blob (the :class:`Segmenter` contract), so the class also
    serves the single-object sources.
    """

    def __init__(
        self,
        subtractor: BackgroundSubtractionSegmenter | None = None,
        min_area: int = MIN_BLOB_AREA,
        **kwargs: Any,
    ) -> None:
        super().__init__(subtractor, **kwargs)
        self.min_area = int(min_area)

    def blobs(self, frame: PerceptionFrame, camera: str) -> list[np.ndarray]:
        if camera not in self._fitted:
            raise RuntimeError(f"BlobSegmenter.blobs before reset for camera {camera!r}")
        t0 = time.perf_counter()
        excluded = self._arm_now(frame, camera) | self._reference_arm[camera]
        t1 = time.perf_counter()
        fitted = self._fitted[camera]
        rgb = np.asarray(frame.observation[f"{camera}_rgb"])
        fg = fitted.foreground(rgb, excluded)
        out = components(fg, self.min_area, fitted.fill_holes, excluded)
        self._excluded[camera] = excluded
        t2 = time.perf_counter()
        self.timings_ms = {"arm_mask": 1e3 * (t1 - t0), "subtract": 1e3 * (t2 - t1)}
        return out

    def segment(self, frame: PerceptionFrame, camera: str) -> np.ndarray | None:
        found = self.blobs(frame, camera)
        return found[0] if found else None


class ClutterPoseSource:
    """The target's pose among several objects, from one fixed camera's images.

    ``models`` (a :class:`PoseModelSet` or its file) must hold every class that may be on the
    table: recognition decides among them. ``recognizer`` is a name from
    :mod:`scorbot_gym.perception.recognizers` or an object (reading one camera's silhouette and
    view). ``splitter`` names the stage that splits blobs several objects share
    (:mod:`scorbot_gym.perception.splitters`; ``"none"``: blobs stay whole) or is one. The
    target's identity is the task command, so the wrapper must pass it (``identity="given"``,
    the env's ``target_class`` / ``info["object_name"]``). ``support`` refines the target's
    estimate as for ``manifold`` (:mod:`scorbot_gym.perception.support`; ``"table"`` by
    default, the prior the clutter figures were measured with; ``"table_memory"``, its votes
    from clear views of the chosen blob; ``"none"``).
    """

    privileged = False

    def __init__(
        self,
        models: PoseModelSet | str | os.PathLike,
        recognizer: str | Any = "flr+appearance",
        segmenter: BlobSegmenter | None = None,
        cameras: Sequence[str] | None = None,
        track_gate_px: float = TRACK_GATE_PX,
        splitter: str | Any = "none",
        support: TableSupport | TableSupportMemory | str | None = "table",
    ) -> None:
        self.models = _load(models)
        self.support = make_support(support)
        meta = self.models.meta
        self.camera = str(meta.get("camera", "top"))
        self.width, self.height = int(meta.get("width", 640)), int(meta.get("height", 480))
        if cameras is not None and list(cameras) not in ([], [self.camera]):
            raise ValueError(
                f"manifold_clutter estimates from its models' camera {self.camera!r} only, got "
                f"cameras={list(cameras)}"
            )
        self.segmenter = segmenter if segmenter is not None else BlobSegmenter()
        if recognizer is not None:  # None: the blob-choice baselines recognise nothing
            check_recognizer(recognizer)
        self.recognizer = recognizer
        self.splitter = splitter
        self._splitter: Any = None  # built on first use (the keypoint one indexes the models)
        self.track_gate_px = float(non_negative("track_gate_px", track_gate_px))
        self._recognizer: Any = None
        self._last: WorldPose | None = None
        self._known: list[tuple[dict, str]] = []  # (blob record, label) recognised this episode
        self._seen: tuple | None = None  # (blobs, records, chosen, pose, camera) of the last step

    @property
    def required_keys(self) -> tuple[str, ...]:
        return (f"{self.camera}_rgb",)

    @property
    def env_requirements(self) -> dict:
        return {
            "cameras": [self.camera],
            "image_width": self.width,
            "image_height": self.height,
            "image_types": ["rgb"],
            **self.segmenter.env_kwargs,
        }

    def reset(self, frame: PerceptionFrame, rng: np.random.Generator) -> None:
        self._last, self._known, self._seen = None, [], None
        self.segmenter.reset(frame, self.camera)
        reset_support(self.support)
        self._reset_splitter()
        if self._recognizer is None and len(self.models.object_names) > 1:
            self._recognizer = make_recognizer(
                self.recognizer, self.models, [self.camera], self.width, self.height
            )

    def _reset_splitter(self) -> None:
        """Build the splitter on first use (the keypoint one indexes every model's training
        descriptors: seconds, outside any timed step) and make it forget the last table."""
        if self._splitter is None:
            self._splitter = make_splitter(self.splitter, self.models)
        if hasattr(self._splitter, "reset"):
            self._splitter.reset()

    # --- estimate ------------------------------------------------------------------------------
    def estimate(self, frame: PerceptionFrame) -> WorldPose:
        target = frame.object_name
        if target is None:
            raise ValueError(
                "manifold_clutter estimates the target named by the task command: wrap the env "
                "with identity='given'"
            )
        cam = frame.cameras[self.camera]
        image = np.asarray(frame.observation[f"{self.camera}_rgb"])
        t0 = time.perf_counter()
        components = self.segmenter.blobs(frame, self.camera)
        t1 = time.perf_counter()
        regions = self._splitter.split(image, components, cam) if components else []
        timings = {"segment": (time.perf_counter() - t0) * 1e3}
        timings.update({f"segment_{k}": v for k, v in self.segmenter.timings_ms.items()})
        timings["segment_split"] = (time.perf_counter() - t1) * 1e3
        if not regions:
            return WorldPose.invalid("no object in view", object_name=target, timings_ms=timings)
        blobs = [r.mask for r in regions]
        records = [_blob_record(r.mask, r.component, r.label) for r in regions]
        t0 = time.perf_counter()
        chosen, est = self._follow(blobs, cam, image, target)
        how = "followed"
        if est is None:
            chosen, est = self._recognise_all(blobs, records, cam, image, target)
            how = "recognised"
        timings["recognise"] = (time.perf_counter() - t0) * 1e3
        timings["estimate"] = 0.0  # made while choosing, timed under "recognise"
        if est is None:
            pose = WorldPose.invalid(
                "target not found among the blobs",
                object_name=target,
                timings_ms=timings,
                camera=self.camera,
            )
        else:
            pose = _world_pose(est, cam, target, timings, self.camera)
            if self.support is not None:  # a clear view of the chosen blob may vote (memory)
                excluded = getattr(self.segmenter, "excluded", lambda c: None)(self.camera)
                clear = lambda: view_is_clear(blobs[chosen], excluded)  # noqa: E731
                pose = refine_pose(self.support, pose, cam, clear)
        pose.details = {
            **pose.details,
            "blobs": records,
            "chosen": chosen,
            "how": how,
            "n_components": len(components),  # blobs before splitting
        }
        self._seen = (blobs, records, chosen, pose, cam)
        if pose.valid:
            self._last = pose
        return pose

    def neighbours(self, frame: PerceptionFrame) -> np.ndarray:
        """The other objects seen at the last :meth:`estimate`, as table-plane points ``(N, 3)``
        (:func:`~scorbot_gym.perception.neighbours.mask_points`): every blob but the target's,
        and what the target's blob holds beyond the target's own projected outline (objects
        touching in the image share a blob). A blob's height is that of the tallest way up of
        the class it was recognised as, else :data:`~scorbot_gym.perception.neighbours.
        UNKNOWN_HEIGHT` (one camera measures no height)."""
        from scorbot_gym.perception.neighbours import UNKNOWN_HEIGHT, mask_points
        from scorbot_gym.sim.scene import TABLE_HEIGHT

        if self._seen is None:
            return np.zeros((0, 3))
        blobs, records, chosen, pose, cam = self._seen
        points = [np.zeros((0, 3))]
        for i, blob in enumerate(blobs):
            label = records[i]["recognised"] or self._remembered(records[i])
            if i == chosen:
                blob, label = self._beyond_target(blob, pose, cam), None
                if blob is None:
                    continue
            height = UNKNOWN_HEIGHT if label is None else _tallest(label)
            points.append(mask_points(blob, cam, TABLE_HEIGHT, height))
        return np.vstack(points)

    def _beyond_target(self, blob: np.ndarray, pose: WorldPose, cam: Any) -> np.ndarray | None:
        """The part of the target's blob outside the target's projected outline (grown by a
        few pixels), if it is large enough to be an object: a neighbour sharing the blob."""
        import cv2

        from scorbot_gym.objects import get_object

        if not pose.valid:
            return None
        verts = get_object(pose.object_name).mesh_vertices()
        uv = cam.project(verts[:: max(1, len(verts) // 500)] @ pose.rotation.T + pose.position)
        outline = np.zeros(blob.shape, np.uint8)
        cv2.fillConvexPoly(outline, cv2.convexHull(np.round(uv).astype(np.int32)), 1)
        outline = cv2.dilate(outline, np.ones((2 * OUTLINE_GROW_PX + 1,) * 2, np.uint8))
        rest = blob.astype(bool) & ~outline.astype(bool)
        return rest if rest.sum() >= self.segmenter.min_area else None

    def _follow(
        self, blobs: list[np.ndarray], cam: Any, image: np.ndarray, target: str
    ) -> tuple[int | None, Any]:
        """The blob nearest the last valid estimate's projection, if within the gate and the
        target's model gives a valid estimate on it."""
        if self._last is None:
            return None, None
        uv = cam.project(self._last.position[None])[0]
        dists = [_distance_to_blob(b, uv) for b in blobs]
        i = int(np.argmin(dists))
        if dists[i] > self.track_gate_px:
            return None, None
        est = self.models.predict(View(image, cam, blobs[i], target))
        return (i, est) if est.valid else (None, None)

    def _recognise_all(
        self,
        blobs: list[np.ndarray],
        records: list[dict],
        cam: Any,
        image: np.ndarray,
        target: str,
    ) -> tuple[int | None, Any]:
        """Recognise every blob; the target's blob is the one recognised as it with the most
        inliers, else an unrecognised one where the target's model explains the most inliers;
        ``(None, None)`` when the target is not found."""
        best: tuple[int, Any] | None = None
        for i, blob in enumerate(blobs):
            view = View(image, cam, blob, None)
            label, est = None, None
            if self._recognizer is not None:
                label = self._remembered(records[i])
                if label is None:
                    rec = self._recognize(blob, view)
                    label = rec.label
                    est = rec.estimates.get(target) if rec.estimates else None
                    if label is not None:
                        self._known.append((records[i], label))
            records[i]["recognised"] = label if self._recognizer is not None else target
            if label == target or self._recognizer is None:
                est = est or self.models.predict(View(image, cam, blob, target))
                if est.valid and (best is None or est.n_inliers > best[1].n_inliers):
                    best = (i, est)
        if best is not None:
            return best
        # No blob recognised as the target: the unrecognised blob where the target's model
        # explains the most inliers. Blobs recognised as other objects are tried only until
        # the target is first found: two objects touching in the image share one blob, which
        # is recognised as one of them, and the target's model explains its own keypoints on
        # it; once an estimate exists, a lost target is one the arm hides, and its model would
        # be fitted to a neighbour (the held estimate stands instead).
        unknown = [
            i for i, r in enumerate(records) if r["recognised"] is None or self._last is None
        ]
        fits = {i: self.models.predict(View(image, cam, blobs[i], target)) for i in unknown}
        valid = {i: f for i, f in fits.items() if f.valid}
        if not valid:
            return None, None
        i = max(valid, key=lambda k: valid[k].n_inliers)
        return i, valid[i]

    def _remembered(self, record: dict) -> str | None:
        """The label of a blob recognised earlier in the episode at about the same place and
        size: objects other than the target stay put while the arm works, and recognising each
        of them again at every step would cost one estimate per shortlisted class."""
        c, area = np.asarray(record["centroid_px"]), record["area"]
        for known, label in self._known:
            near = np.linalg.norm(c - known["centroid_px"]) <= self.track_gate_px
            if near and 0.5 <= area / known["area"] <= 2.0:
                return label
        return None

    def _recognize(self, blob: np.ndarray, view: View) -> Any:
        rec = self._recognizer
        reads = getattr(rec, "reads", "view")
        if reads == "silhouettes":
            return rec.recognize({self.camera: blob})
        if reads == "silhouettes+view":
            return rec.recognize({self.camera: blob}, view)
        return rec.recognize(view)


def _tallest(name: str) -> float:
    """The object's height (m) standing on its tallest resting pose."""
    from scorbot_gym.objects import get_object
    from scorbot_gym.sim.simulation import quat_to_mat

    spec = get_object(name)
    z = [spec.mesh_vertices() @ quat_to_mat(q)[2] for q in spec.resting_quats]
    return float(max(np.ptp(h) for h in z))


def _blob_record(blob: np.ndarray, component: int = 0, split_label: str | None = None) -> dict:
    """A blob for the record: its size and place, the connected component it was split from
    and the class whose keypoints seeded it (``None``: left whole), and its recognition."""
    ys, xs = np.nonzero(blob)
    return {
        "area": int(len(xs)),
        "centroid_px": [float(xs.mean()), float(ys.mean())],
        "component": int(component),
        "split_label": split_label,
        "recognised": None,
    }


def _distance_to_blob(blob: np.ndarray, uv: np.ndarray) -> float:
    """Pixels from ``uv`` to the nearest pixel of ``blob`` (0 inside it)."""
    ys, xs = np.nonzero(blob)
    return float(np.sqrt(((xs - uv[0]) ** 2 + (ys - uv[1]) ** 2).min()))
