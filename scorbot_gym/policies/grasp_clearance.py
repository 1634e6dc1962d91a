"""Where the open hand comes down: a grasp chosen to keep the fingers off the neighbours.

On a cluttered table the scripted grasp failed where the target alone never does: in every one
of the 23 failed oracle episodes of the 200-episode benchmark (2 distractors) an open finger
came down on a neighbour during the descent, which then wedged against the finger at closing,
pushed the target away, or blew the physics up (``benchmarks/clutter_approach.py``). The hand's
footprint seen from above is fixed by the closing line: two fingers ``aperture / 2`` either side
of the grasp point along it and the palm across it, so the planner has three choices left:

- **which of the grasp's equivalent closing lines**: an object symmetric about its vertical axis
  (a can, a ball, a square cube) is grasped the same way along every line its symmetry maps the
  nominal one to (:meth:`pose.symmetry.Symmetry.rotations`);
- **where along the object**, for an object with a single closing line (a box, a marker, a
  lego brick, a banana): off its centre along its length, where its section across the line
  is the centre's (:func:`grasp_candidates`);
- **how wide to open** (the pre-grasp aperture, as a human hand shapes its grip to the object):
  the object's width in the fingers' band plus ``margin`` on each side, not the gripper's full
  75 mm, so the fingers of a narrow object (a marker: 18 mm) land 16 mm closer to it a side.

Among the candidates the planner takes the one whose footprint keeps the largest clearance from
the neighbours, counted up to :data:`COMFORTABLE_CLEARANCE` (beyond it every candidate is as
good and the nominal one is kept: with nothing near, the object is grasped as before).

Neighbours are points on the table plane with the height of the object top there
(``neighbour_points``, from :class:`~scorbot_gym.wrappers.pose_observation.
PoseEstimateObservation`): a finger collides with any neighbour it comes down on; the palm,
``palm_above_tcp`` above the grasp point, only with a neighbour taller than that (the hand's
geometry is read from the arm's own model: :attr:`~scorbot_gym.robot.ArmKinematics.hand`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scorbot_gym.objects import ObjectSpec
from scorbot_gym.robot.kinematics import HandGeometry, horizontal_closing_yaw, wrap_half_turn

#: clearance (m) beyond which every closing line is as good as another
COMFORTABLE_CLEARANCE = 0.015
#: free space (m) left on each side of the object between it and the open fingers
APERTURE_MARGIN = 0.012
#: an axial symmetry is tried every this many degrees
AXIAL_STEP_DEG = 15.0
#: a candidate nearer the previous choice wins ties within this clearance (m): no flip-flopping
HYSTERESIS = 0.004
#: spacing (m) of off-centre grasps along an object with a single closing line
SLIDE_STEP = 0.005
#: an off-centre grasp leaves at least this much (m) of the object beyond the finger
END_MARGIN = 0.01
#: an off-centre grasp is taken only where the object's section across the closing line lies
#: within this much (m) of the centre's, on both sides (a prism, a marker's barrel: the same grasp)
SLIDE_WIDTH_TOLERANCE = 0.003


@dataclass(frozen=True)
class GraspCandidate:
    """One equivalent grasp: its closing-line heading (world, rad), grasp point offset from the
    nominal one (world, m), the aperture it needs (m), its clearance from the neighbours (m;
    ``inf`` without neighbours, negative where the hand overlaps one) and how far it slides
    along the object (m)."""

    yaw: float
    offset: np.ndarray
    aperture: float
    clearance: float
    slide: float = 0.0  # m off the object's centre, across the closing line


def closing_axes(spec: ObjectSpec, R: np.ndarray) -> list[np.ndarray]:
    """The object's rotation composed with each of its symmetries that keep the grasp the same
    (identity first): the rotations under which the object looks and grasps the same."""
    rots = spec.symmetry.rotations(step_deg=AXIAL_STEP_DEG)
    return [R @ S for S in rots]


def object_section(
    vertices: np.ndarray, edges: np.ndarray, yaw: float, grasp_xy: np.ndarray, band: float
) -> tuple[float, float, float]:
    """Where the object lies along the closing line (heading ``yaw``) through ``grasp_xy``,
    within the band a finger sweeps across it (``band`` either side of the line): its nearest
    and farthest extent along the line (signed, m), and how far the object extends across the
    line (m); ``vertices`` are the object's world vertices relative to its origin, ``edges`` the
    mesh's vertex-index pairs. Exact for the mesh: the vertices inside the band and the points
    where edges cross its borders (a box's 8 vertices may all lie outside it). ``(-inf, inf)``
    where the band misses the object."""
    xy = vertices[:, :2] - grasp_xy
    u = np.array([np.cos(yaw), np.sin(yaw)])
    along, across = xy @ u, xy @ np.array([-u[1], u[0]])
    points = [along[np.abs(across) <= band]]
    a, b = edges[:, 0], edges[:, 1]
    for border in (-band, band):
        da, db = across[a] - border, across[b] - border
        cut = da * db < 0
        s = da[cut] / (da[cut] - db[cut])
        points.append(along[a[cut]] + s * (along[b[cut]] - along[a[cut]]))
    section = np.concatenate(points)
    extent = float(np.abs(across).max())
    if not len(section):
        return -np.inf, np.inf, extent
    return float(section.min()), float(section.max()), extent


def hand_clearance(
    points: np.ndarray, grasp: np.ndarray, yaw: float, aperture: float, hand: HandGeometry
) -> float:
    """Smallest table-plane distance (m) from ``points`` (``(N, 3)``: x, y and the height of
    the object top there) to the hand coming down vertically at ``grasp`` with its fingers
    ``aperture`` apart along heading ``yaw``: both fingers for every point, the palm for points
    higher than its underside. Negative inside a footprint, ``inf`` for no points."""
    if len(points) == 0:
        return float("inf")
    u = np.array([np.cos(yaw), np.sin(yaw)])
    w = np.array([-u[1], u[0]])
    d = points[:, :2] - grasp[:2]
    along, across = d @ u, d @ w
    half_t = hand.finger_thickness / 2
    centre = aperture / 2 + half_t
    fingers = np.minimum(
        _box_distance(along - centre, across, half_t, hand.finger_half_width),
        _box_distance(along + centre, across, half_t, hand.finger_half_width),
    )
    palm = _box_distance(along, across, hand.palm_half_length, hand.palm_half_width)
    palm = np.where(points[:, 2] > grasp[2] + hand.palm_above_tcp, palm, np.inf)
    return float(np.minimum(fingers, palm).min())


def _box_distance(x: np.ndarray, y: np.ndarray, hx: float, hy: float) -> np.ndarray:
    """Signed distance from points ``(x, y)`` to the centred box of half sizes ``hx, hy``."""
    dx, dy = np.abs(x) - hx, np.abs(y) - hy
    outside = np.hypot(np.maximum(dx, 0.0), np.maximum(dy, 0.0))
    return np.where((dx > 0) | (dy > 0), outside, np.maximum(dx, dy))


def choose_grasp(
    candidates: list[GraspCandidate],
    previous: GraspCandidate | None = None,
    comfortable_m: float = COMFORTABLE_CLEARANCE,
) -> GraspCandidate:
    """The candidate with the most clearance, counted up to ``comfortable_m``; ties go to the
    one nearest ``previous`` (the current plan: no wrist turn or slide for nothing), and
    without one to the nominal grasp (the first). The candidate nearest the previous choice
    keeps its place unless another is clearer by more than :data:`HYSTERESIS`."""
    ref = candidates[0] if previous is None else previous

    def change(c: GraspCandidate) -> float:
        return _change(c, ref)

    kept = min(candidates, key=change)
    score = {id(c): min(c.clearance, comfortable_m) for c in candidates}
    best = max(candidates, key=lambda c: (score[id(c)], -change(c)))
    if previous is not None and score[id(best)] <= score[id(kept)] + HYSTERESIS:
        return kept
    return best


def same_grasp(candidates: list[GraspCandidate], previous: GraspCandidate) -> GraspCandidate:
    """The candidate nearest ``previous``: the grasp kept while the arm comes down (the arm
    hides part of the table from a camera above it by then, so the choice is not made anew)."""
    return min(candidates, key=lambda c: _change(c, previous))


def _change(c: GraspCandidate, ref: GraspCandidate) -> float:
    """How far apart two grasps are: wrist turn (rad), a slide of 5 cm counting a quarter turn."""
    return abs(wrap_half_turn(c.yaw - ref.yaw)) + abs(c.slide - ref.slide) * np.pi / 2 / 0.05


def grasp_candidates(
    spec: ObjectSpec,
    R: np.ndarray,
    position: np.ndarray,
    grasp: np.ndarray,
    closing_yaw: float,
    neighbours: np.ndarray,
    hand: HandGeometry,
    margin: float | None = APERTURE_MARGIN,
) -> list[GraspCandidate]:
    """The grasp ``(grasp, closing_yaw)`` planned for the object at ``position`` under ``R``
    and its equivalents, each with its aperture (``margin`` each side of the object; ``None``:
    the full opening) and clearance from ``neighbours``; the first is the nominal one.

    Equivalents: the closing lines the object's symmetry maps the nominal one to, offered only
    while the symmetry axis stands within ~10 degrees of vertical (otherwise a symmetry turns
    the object about a leaning axis and its closing line is not the nominal one turned about
    the vertical). An object with a single closing line (a box, a marker, a banana) may instead
    be grasped off its centre, along the object: by up to a quarter of its length, never
    nearer its end than :data:`END_MARGIN` beyond the finger, every :data:`SLIDE_STEP`, and
    only where its cross-section is the centre's (:data:`SLIDE_WIDTH_TOLERANCE`)."""
    model = spec.model
    gp = np.r_[model.grasp_point, 0.0]
    nominal_point = position + R @ gp
    axis = R @ np.asarray(spec.symmetry.axis)
    upright = abs(axis[2]) >= np.cos(np.radians(10.0))
    base_yaw = horizontal_closing_yaw(R, model.grasp_yaw)
    lines: list[tuple[float, np.ndarray]] = []  # (yaw, grasp point offset)
    for Rs in closing_axes(spec, R) if upright else [R]:
        yaw = closing_yaw + wrap_half_turn(horizontal_closing_yaw(Rs, model.grasp_yaw) - base_yaw)
        if any(abs(wrap_half_turn(yaw - y)) < np.radians(1.0) for y, _ in lines):
            continue  # the same closing line (a half turn, a flip)
        lines.append((yaw, (position + Rs @ gp) - nominal_point))
    verts = model.vertices @ R.T
    edges = _edges(spec)
    rel = (grasp - position)[:2]
    band = hand.finger_half_width
    lo, hi, length = object_section(verts, edges, closing_yaw, rel, band)
    nominal = np.array([lo, hi])
    slides = [0.0]
    if len(lines) == 1 and np.isfinite(nominal).all():  # one line: slide along the object
        room = min(length - band - END_MARGIN, length / 2)
        steps = np.arange(SLIDE_STEP, room + 1e-9, SLIDE_STEP)
        slides += [s for step in steps for s in (step, -step)]
    out: list[GraspCandidate] = []
    for yaw, offset in lines:
        across = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        for slide in slides:
            shift = offset + slide * across
            point = grasp + shift
            section = nominal
            if slide:  # the object where the fingers now close must be as it is at the centre
                section = np.array(
                    object_section(verts, edges, yaw, (point - position)[:2], band)[:2]
                )
                if np.abs(section - nominal).max() > SLIDE_WIDTH_TOLERANCE:
                    continue  # a banana's curve, a rounded end: not the grasp planned
            reach = float(np.abs(section).max())
            aperture = hand.max_opening
            if margin is not None:
                aperture = min(aperture, 2 * (reach + margin))
            clearance = hand_clearance(neighbours, point, yaw, aperture, hand)
            out.append(GraspCandidate(yaw, shift, aperture, clearance, slide))
    return out


_EDGES: dict[str, np.ndarray] = {}


def _edges(spec: ObjectSpec) -> np.ndarray:
    """The mesh's edges as vertex-index pairs (each once), built once per object."""
    if spec.name not in _EDGES:
        f = spec.model.faces
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        _EDGES[spec.name] = np.unique(e, axis=0)
    return _EDGES[spec.name]
