"""Named, seeded, versioned evaluation protocols for pose estimators.

A protocol fixes what an estimator is trained on and what it is tested on: the cameras, how
training poses are sampled, how test poses are sampled, and the occlusion levels. Ablations,
the ``pose ablate`` CLI and the benchmarks all take protocols by name, so a figure always says
which protocol (and which version of it) produced it. Changing what a protocol samples means
bumping its ``version``.

- ``top-resting``: the top camera, objects resting on a face (the protocol of the original
  benchmark: in-plane headings, which a homography to the nearest training view recovers).
- ``side-turntable`` / ``overview``: trained and tested on that camera; the heading is an
  out-of-plane rotation there (turntable-like views: the seed's own setting).
- ``tilted``: top camera, objects leaning up to 30° out of a resting pose (propped or held):
  a 3-D estimate, not a face lookup. Training sees tilts too (sampled, not the test ones).
- ``sparse-headings``: side camera, training headings 30° apart, tests exactly halfway between
  (the seed's claim that the manifold + RBF *interpolates* between known poses).
- ``cross-camera``: trained on the top and side cameras, tested on the overview camera.
- ``clutter``: side camera, trained as ``side-turntable``; each test view puts the target among
  three other catalogue objects, some on the camera's side of it (real occluders,
  :mod:`scorbot_gym.data.clutter_views`). The occlusion is *measured* from the segmentation,
  and a level is a bin of it: level ``o`` holds the views whose measured occlusion lies in
  ``[o, o + 10 %)`` (:data:`CLUTTER_BINS`), so the bins hold different numbers of views.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from scorbot_gym.data.perturbations import Perturbation
from scorbot_gym.data.views import (
    LabelledView,
    PoseSample,
    grid_poses,
    random_poses,
    render_views,
    workspace_bounds,
)

#: the seed's occlusion axis: 0-95 % in 5 % steps
OCCLUSION_LEVELS = tuple(round(0.05 * i, 2) for i in range(20))
MAX_TILT = np.radians(30.0)
#: the ``clutter`` protocol's levels: lower edges of 10 % bins of measured occlusion
CLUTTER_BINS = tuple(round(0.1 * i, 2) for i in range(10))

Sampler = Callable[[int, int], list[PoseSample]]  # (n_resting, seed) -> samples


def _grid(yaw_step_deg: float, n_positions: int = 2) -> Sampler:
    def sample(n_resting: int, seed: int) -> list[PoseSample]:
        return grid_poses(n_resting, yaw_step_deg, workspace_bounds(), n_positions, seed)

    return sample


def _random(n: int) -> Sampler:
    def sample(n_resting: int, seed: int) -> list[PoseSample]:
        return random_poses(n, n_resting, workspace_bounds(), seed)

    return sample


def tilted_poses(n: int, n_resting: int, seed: int, max_tilt: float = MAX_TILT) -> list[PoseSample]:
    """``n`` random positions, headings and resting faces (:func:`random_poses` in the
    workspace), each tilted out of its resting pose by an angle uniform in ``[0, max_tilt]``
    (radians) towards a uniform direction: objects propped on a stand or leaning."""
    rng = np.random.default_rng(seed)
    base = random_poses(n, n_resting, workspace_bounds(), seed)
    tilts = rng.uniform(0.0, max_tilt, n)
    dirs = rng.uniform(-np.pi, np.pi, n)
    return [
        PoseSample(s.x, s.y, s.yaw, s.resting_index, float(t), float(d))
        for s, t, d in zip(base, tilts, dirs, strict=True)
    ]


def _tilted(n: int, max_tilt: float = MAX_TILT) -> Sampler:
    """Random resting face, heading and position, tilted by up to ``max_tilt`` (uniform in the
    tilt angle, uniform tilt direction)."""

    def sample(n_resting: int, seed: int) -> list[PoseSample]:
        return tilted_poses(n, n_resting, seed, max_tilt)

    return sample


def _midpoints(n: int, step_deg: float = 30.0) -> Sampler:
    """Random positions and faces, headings exactly halfway between the training grid's."""

    def sample(n_resting: int, seed: int) -> list[PoseSample]:
        rng = np.random.default_rng(seed)
        base = random_poses(n, n_resting, workspace_bounds(), seed)
        k = rng.integers(0, round(360 / step_deg), n)
        yaws = np.radians(step_deg * (k + 0.5))
        return [
            PoseSample(s.x, s.y, float(a), s.resting_index) for s, a in zip(base, yaws, strict=True)
        ]

    return sample


@dataclass(frozen=True)
class PoseProtocol:
    """What to train on and what to test on; see the module docstring for the named ones."""

    name: str
    version: int
    train_cameras: tuple[str, ...]
    test_camera: str
    train_sampler: Sampler
    test_sampler: Sampler
    description: str
    occlusions: tuple[float, ...] = OCCLUSION_LEVELS
    extra: dict = field(default_factory=dict)

    @property
    def clutter_distractors(self) -> int | None:
        """How many other objects share a test view's table (``None``: a synthetic occluder
        pasted over the image instead, at the requested fraction)."""
        return self.extra.get("distractors")

    def train_samples(self, n_resting: int, seed: int = 0) -> list[PoseSample]:
        return self.train_sampler(n_resting, seed)

    def test_samples(self, n_resting: int, seed: int = 1) -> list[PoseSample]:
        return self.test_sampler(n_resting, seed)


_N_TEST = 30
_N_CLUTTER = 150  # views pooled over every bin of measured occlusion

PROTOCOLS: dict[str, PoseProtocol] = {
    p.name: p
    for p in (
        PoseProtocol(
            "top-resting", 1, ("top",), "top", _grid(10.0), _random(_N_TEST),
            "top camera, resting objects, training headings every 10 degrees",
        ),
        PoseProtocol(
            "side-turntable", 1, ("side",), "side", _grid(10.0), _random(_N_TEST),
            "side camera (heading is out-of-plane), training headings every 10 degrees",
        ),
        PoseProtocol(
            "overview", 1, ("overview",), "overview", _grid(10.0), _random(_N_TEST),
            "overview camera, training headings every 10 degrees",
        ),
        PoseProtocol(
            "tilted", 1, ("top",), "top", _tilted(432), _tilted(_N_TEST),
            "top camera, objects tilted up to 30 degrees out of a resting pose",
        ),
        PoseProtocol(
            "sparse-headings", 1, ("side",), "side", _grid(30.0, 4), _midpoints(_N_TEST),
            "side camera, training headings 30 degrees apart, tests halfway between",
        ),
        PoseProtocol(
            "cross-camera", 1, ("top", "side"), "overview", _grid(10.0), _random(_N_TEST),
            "trained on the top and side cameras, tested on the overview camera",
        ),
        PoseProtocol(
            "clutter", 1, ("side",), "side", _grid(10.0), _random(_N_CLUTTER),
            "side camera, the target among 3 other objects; occlusion measured, in 10 % bins",
            CLUTTER_BINS, {"distractors": 3},
        ),
    )
}  # fmt: skip


def protocol_names() -> tuple[str, ...]:
    return tuple(PROTOCOLS)


def get_protocol(name: str) -> PoseProtocol:
    if name not in PROTOCOLS:
        raise ValueError(f"unknown protocol {name!r}; valid: {', '.join(PROTOCOLS)}")
    return PROTOCOLS[name]


def _n_resting(object_name: str) -> int:
    from scorbot_gym.objects import get_object

    return len(get_object(object_name).resting_quats)


def train_views(
    protocol: PoseProtocol | str,
    object_name: str,
    *,
    width: int = 320,
    height: int = 240,
    seed: int = 0,
    depth: bool = False,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = False,
) -> dict[str, list[LabelledView]]:
    """The protocol's training views of one object, keyed by camera (unoccluded)."""
    p = get_protocol(protocol) if isinstance(protocol, str) else protocol
    samples = p.train_samples(_n_resting(object_name), seed)
    return {
        cam: render_views(
            object_name, samples, cam, width, height, 0.0, seed, cache_dir, progress, depth
        )
        for cam in p.train_cameras
    }


def held_out_views(
    protocol: PoseProtocol | str,
    object_name: str,
    occlusion: float,
    *,
    width: int = 320,
    height: int = 240,
    seed: int = 1,
    depth: bool = False,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = False,
    perturbation: Perturbation | None = None,
    n_poses: int | None = None,
) -> list[LabelledView]:
    """The protocol's held-out test views of one object at one occlusion level.

    The poses do not depend on the occlusion level (the same poses at every level, so a curve
    over occlusion compares like with like); the occluders are drawn from ``seed``.
    ``n_poses`` keeps the first ``n_poses`` test poses only (a reduced run; ``None``: all).
    On a clutter protocol those are the scenes rendered (scene ``i`` is the same whatever
    ``n_poses``), and a bin holds those of them whose measured occlusion falls into it; on the
    others each pose is one view per level.
    """
    if n_poses is not None and n_poses < 1:
        raise ValueError(f"n_poses must be >= 1 or None, got {n_poses}")
    p = get_protocol(protocol) if isinstance(protocol, str) else protocol
    samples = p.test_samples(_n_resting(object_name), seed)
    if p.clutter_distractors is not None:
        return _clutter_bin(p, object_name, samples[:n_poses], occlusion, width, height, seed,
                            cache_dir, progress, depth, perturbation)  # fmt: skip
    occ_seed = seed + 1000 * round(100 * occlusion)
    # every pose rendered, then the first n_poses kept: a reduced run reads the full run's cache
    return render_views(
        object_name, samples, p.test_camera, width, height, occlusion, occ_seed, cache_dir,
        progress, depth, perturbation,
    )[:n_poses]  # fmt: skip


def _clutter_bin(
    p: PoseProtocol, object_name, samples, occlusion, width, height, seed, cache_dir, progress,
    depth, perturbation,
) -> list[LabelledView]:  # fmt: skip
    """The views of the bin ``occlusion`` of ``p``'s clutter scenes (rendered once for all)."""
    from scorbot_gym.data.clutter_views import occlusion_bin, render_clutter_views

    if not any(abs(occlusion - b) < 1e-9 for b in p.occlusions):
        levels = ", ".join(f"{100 * b:.0f}" for b in p.occlusions)
        raise ValueError(
            f"protocol {p.name!r} bins its measured occlusion: levels are the bins' lower edges "
            f"({levels} %), got {100 * occlusion:g} %"
        )
    if depth or (perturbation is not None and perturbation.active):
        raise ValueError(f"protocol {p.name!r} renders plain RGB test views: no depth, no "
                         "perturbation")  # fmt: skip
    views = render_clutter_views(
        object_name, samples, p.test_camera, width, height, p.clutter_distractors, seed,
        cache_dir, progress,
    )  # fmt: skip
    return [v for v in views if occlusion_bin(v.occlusion, p.occlusions) == occlusion]


def describe(names: Sequence[str] | None = None) -> list[dict]:
    """JSON-able description of protocols (for result files)."""
    return [
        {
            "name": p.name,
            "version": p.version,
            "train_cameras": list(p.train_cameras),
            "test_camera": p.test_camera,
            "description": p.description,
            **(
                {"distractors": p.clutter_distractors, "occlusion": "measured, binned"}
                if p.clutter_distractors is not None
                else {}
            ),
        }
        for p in (get_protocol(n) for n in (names or protocol_names()))
    ]
