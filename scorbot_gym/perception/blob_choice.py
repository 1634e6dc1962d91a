"""Baselines for a cluttered table: the target's blob chosen without recognising anything.

``manifold_clutter`` splits the foreground into blobs, recognises each and estimates the target
on the blob recognised as it. These sources run the same segmentation and the same pose models
but choose the blob another way, so that an ablation swaps one component (the choice) by name:

- ``largest_blob``: the largest blob (what a single-object pipeline does: no recognition);
- ``random_blob``: a blob drawn at random from the episode's generator (the chance level of
  "grasp a blob": with the target and K distractors apart in the image, right about 1/(K+1) of
  the time).

Either way the chosen blob is **followed** for the rest of the episode (the blob nearest where
it was, within a gate), as ``manifold_clutter`` follows the target: a source that re-drew its
blob at every step would send the arm back and forth and measure nothing. On the chosen blob
the target's pose models estimate; where they find no valid pose (the blob is another object,
whose keypoints the target's model does not explain), the target's model is placed on the blob's
silhouette (:class:`~scorbot_gym.perception.motion.SilhouetteMotion`: resting on the table at
the silhouette's centre, turned to fit it), so the controller grasps that blob, as a picker
without recognition would. Where the chosen blob is lost (the arm hides or cuts it), the source
answers invalid and the held estimate stands, as ``manifold_clutter`` does.
``details["chosen"]`` names the blob taken, which ``PoseEstimateObservation`` scores against
the ground truth like any other pick.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from pose.model_set import PoseModelSet
from pose.view import View
from scorbot_gym.perception.base import PerceptionFrame
from scorbot_gym.perception.clutter import TRACK_GATE_PX, BlobSegmenter, ClutterPoseSource
from scorbot_gym.perception.motion import SilhouetteMotion
from scorbot_gym.sim.simulation import quat_to_mat

#: how a blob is chosen where none was followed yet
BLOB_CHOICES = ("largest", "random")


class BlobChoicePoseSource(ClutterPoseSource):
    """The target's pose on a blob chosen by ``choice`` (``"largest"`` or ``"random"``), with
    no recognition; see the module docstring. ``models`` as for ``manifold_clutter``."""

    def __init__(
        self,
        models: PoseModelSet | str | os.PathLike,
        choice: str = "largest",
        segmenter: BlobSegmenter | None = None,
        track_gate_px: float = TRACK_GATE_PX,
        **kwargs: Any,
    ) -> None:
        if choice not in BLOB_CHOICES:
            raise ValueError(f"choice must be one of {BLOB_CHOICES}, got {choice!r}")
        kwargs.pop("recognizer", None)  # nothing is recognised (accepted for a drop-in swap)
        super().__init__(
            models, recognizer=None, segmenter=segmenter, track_gate_px=track_gate_px, **kwargs
        )
        self.choice = choice
        self._rng = np.random.default_rng(0)
        self._chosen_at: np.ndarray | None = None  # centroid (px) of the blob taken last
        self._silhouette = SilhouetteMotion(min_area=self.segmenter.min_area)
        self._points: dict[str, np.ndarray] = {}

    def reset(self, frame: PerceptionFrame, rng: np.random.Generator) -> None:
        self._last, self._known, self._chosen_at, self._seen = None, [], None, None
        self._rng = rng
        self.segmenter.reset(frame, self.camera)
        self._reset_splitter()

    def _recognise_all(
        self,
        blobs: list[np.ndarray],
        records: list[dict],
        cam: Any,
        image: np.ndarray,
        target: str,
    ) -> tuple[int | None, Any]:
        """The blob taken before (nearest its last centroid, within the gate), else a new one
        by ``choice``; the target's model on it, else the target placed on its silhouette."""
        i = self._choose(records)
        if i is None:
            return None, None
        self._chosen_at = np.asarray(records[i]["centroid_px"], float)
        est = self.models.predict(View(image, cam, blobs[i], target))
        if est.valid:
            return i, est
        placed = self._on_silhouette(blobs[i], cam, target)
        return (i, placed) if placed is not None else (None, None)

    def _choose(self, records: list[dict]) -> int | None:
        """The blob nearest the one taken before (None where none is within the gate: the
        arm hides it, and the held estimate stands), else a new one by ``choice``."""
        if self._chosen_at is not None:
            d = [np.linalg.norm(np.asarray(r["centroid_px"]) - self._chosen_at) for r in records]
            return int(np.argmin(d)) if min(d) <= self.track_gate_px else None
        if self.choice == "random":
            return int(self._rng.integers(len(records)))
        return int(np.argmax([r["area"] for r in records]))

    def _on_silhouette(self, blob: np.ndarray, cam: Any, target: str) -> _Placed | None:
        """The target's first resting pose placed (and turned) to fit ``blob``; None where the
        silhouette cannot place it (cut by the image border or the arm: the held estimate
        stands)."""
        from scorbot_gym.objects import get_object
        from scorbot_gym.sim.scene import TABLE_HEIGHT

        spec = get_object(target)
        if target not in self._points:
            pts = spec.mesh_vertices()
            self._points[target] = pts[:: max(1, len(pts) // 300)]
        R = quat_to_mat(np.asarray(spec.resting_quats[0], float))
        lowest = float((self._points[target] @ R.T)[:, 2].min())
        ys, xs = np.nonzero(blob)
        z = TABLE_HEIGHT - lowest + 5e-4
        try:
            xy = cam.backproject_to_plane(np.array([[xs.mean(), ys.mean()]]), z)[0][:2]
        except ValueError:
            return None
        found = self._silhouette.locate(
            blob, self.segmenter.excluded(self.camera), cam, np.r_[xy, z], R,
            self._points[target],
        )  # fmt: skip
        return None if found is None else _Placed(*found, cam)

    def _follow(
        self, blobs: list[np.ndarray], cam: Any, image: np.ndarray, target: str
    ) -> tuple[int | None, Any]:
        i, est = super()._follow(blobs, cam, image, target)
        if i is not None:  # where the followed blob is now, should the models lose it later
            ys, xs = np.nonzero(blobs[i])
            self._chosen_at = np.array([xs.mean(), ys.mean()])
        return i, est


class _Placed:
    """A silhouette placement in the camera frame, the form of the models' estimates, so that
    it flows through the same conversion to the world frame."""

    valid = True
    reason = "placed on the blob's silhouette"
    confidence = 0.5
    n_keypoints = 0
    n_inliers = 0

    def __init__(self, position: np.ndarray, rotation: np.ndarray, cam: Any) -> None:
        T = cam.camera_from_world
        self.rotation = T[:3, :3] @ np.asarray(rotation, float)
        self.translation = T[:3, :3] @ np.asarray(position, float) + T[:3, 3]
