"""Checks of :class:`~scorbot_gym.envs.grasp.ScorbotGraspEnv`'s keyword arguments.

Every keyword is checked when the environment is made, so a typo fails at ``gym.make`` with one
line naming the argument and what it accepts, instead of deep inside MuJoCo, numpy or the first
``step`` (a NaN step size used to reach the servos as NaN controls).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from numbers import Real
from typing import Any

import numpy as np

from scorbot_gym.objects import CATALOGUE, ObjectSpec, get_object

# Physics substeps per control step: 1 s of simulated time per step at the 2 ms timestep.
MAX_FRAME_SKIP = 500
# Largest per-step action scales: beyond these one step moves more than the arm's whole range.
MAX_STEP_SCALE = {
    "max_joint_step": math.pi,  # rad
    "max_cartesian_step": 0.5,  # m
    "max_angle_step": math.pi,  # rad
}


def positive_float(name: str, value: Any, high: float) -> float:
    """``value`` as a float in (0, high]; ValueError naming ``name`` otherwise (NaN included)."""
    if isinstance(value, bool) or not isinstance(value, Real) or not 0.0 < value <= high:
        raise ValueError(f"{name} must be a finite number in (0, {high:.4g}], got {value!r}")
    return float(value)


def step_scale(name: str, value: Any) -> float:
    """An action scale (``max_joint_step`` ...) in (0, :data:`MAX_STEP_SCALE`]."""
    return positive_float(name, value, MAX_STEP_SCALE[name])


def int_in_range(name: str, value: Any, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an int in [{low}, {high}], got {value!r}")
    if not low <= value <= high:
        raise ValueError(f"{name} must be in [{low}, {high}], got {value}")
    return int(value)


def flag(name: str, value: Any) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def name_list(name: str, value: Any, example: str) -> tuple[str, ...]:
    """A sequence of names as a tuple; a bare string is refused (it would be read as letters)."""
    if isinstance(value, str):
        raise ValueError(f"{name} must be a list of names, e.g. {name}=[{value!r}], got {value!r}")
    if not isinstance(value, Sequence) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"{name} must be a list of names such as [{example!r}], got {value!r}")
    if len(set(value)) != len(value):
        raise ValueError(f"{name} must not repeat a name, got {list(value)}")
    return tuple(value)


#: the steepest stand (``tilt_deg``): the default pose models are trained on views tilted up
#: to 30 degrees (``perception.training.IN_LOOP_TRAINING``), so the env offers no steeper scene
MAX_TILT_DEG = 30.0

RESET_OPTIONS = ("object_name", "target", "resting_index")
_TARGET_KEYS = ("target", "object_name")  # two names for the object to grasp


def reset_options(options: Any) -> dict:
    """``reset``'s ``options`` as a dict (``None``: no options); anything else, and a key that
    is not one of :data:`RESET_OPTIONS`, is refused (a typo would be silently ignored)."""
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise ValueError(
            f"options must be a dict or None (keys: {', '.join(RESET_OPTIONS)}), got {options!r}"
        )
    unknown = [k for k in options if k not in RESET_OPTIONS]
    if unknown:
        raise ValueError(
            f"unknown reset option{'s' if len(unknown) > 1 else ''} "
            f"{', '.join(map(repr, unknown))}; valid keys: {', '.join(RESET_OPTIONS)}"
        )
    return dict(options)


def reset_target(options: Mapping[str, Any], targets: Sequence[str]) -> str | None:
    """The object named by ``options["target"]`` (or its synonym ``"object_name"``), which must
    be one of the env's ``targets``; ``None`` where neither is given (the env draws one)."""
    given = {k: options[k] for k in _TARGET_KEYS if options.get(k) is not None}
    if len(given) == 2 and given["target"] != given["object_name"]:
        raise ValueError(
            "options['target'] and options['object_name'] both name the object to grasp; give "
            f"one, got {given['target']!r} and {given['object_name']!r}"
        )
    if not given:
        return None
    key, name = next(iter(given.items()))
    if not isinstance(name, str) or name not in targets:
        raise ValueError(
            f"options[{key!r}]: target {name!r} is not one of this env's targets "
            f"{list(targets)} (make the env with objects=[...] to grasp others)"
        )
    return name


def resting_index(value: Any, spec: ObjectSpec) -> int:
    """``options["resting_index"]``: an int that numbers one of ``spec``'s resting faces."""
    n_resting, object_name = len(spec.resting_quats), spec.name
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(
            f"options['resting_index'] must be an int in [0, {n_resting - 1}] ({object_name} has "
            f"{n_resting} resting faces), got {value!r}"
        )
    if not 0 <= value < n_resting:
        raise ValueError(
            f"options['resting_index'] must be in [0, {n_resting - 1}] ({object_name} has "
            f"{n_resting} resting faces), got {value}"
        )
    return int(value)


def object_names(object_name: str | None, objects: Sequence[str] | None) -> tuple[str, ...]:
    """Canonical catalogue names from ``object_name`` or ``objects`` (None: whole catalogue)."""
    if object_name is not None and objects is not None:
        raise ValueError("give object_name or objects, not both")
    if object_name is not None:
        if not isinstance(object_name, str):
            raise ValueError(f"object_name must be a catalogue name, got {object_name!r}")
        names: tuple[str, ...] = (object_name,)
    elif objects is None:
        names = tuple(CATALOGUE)
    else:
        names = name_list("objects", objects, "tomato_soup_can")
        if not names:
            raise ValueError(
                "objects must name at least one catalogue object (None means all of them)"
            )
    return tuple(get_object(n).name for n in names)  # KeyError lists the valid names


def distractors(value: Any, objects: Sequence[str], explicit: bool) -> int | tuple[str, ...]:
    """``distractors``: how many of ``objects`` to put beside the target (drawn per episode), or
    a list of catalogue names always on the table (canonical names). Named distractors may not
    be possible targets when ``objects`` were given (``explicit``); otherwise the env leaves them
    out of its targets."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        if not 0 <= value < len(objects):
            raise ValueError(
                f"distractors must be in [0, {len(objects) - 1}] (drawn from the env's "
                f"{len(objects)} objects beside the target), got {value}"
            )
        return int(value)
    names = name_list("distractors", value, "banana")
    names = tuple(get_object(n).name for n in names)  # KeyError lists the valid names
    both = sorted(set(names) & set(objects))
    if both and explicit:
        raise ValueError(
            f"distractors {both} are also possible targets (objects); name targets with "
            "objects=[...] and distractors with distractors=[...], or give distractors=K"
        )
    return names


def tilt_deg(value: Any, high: float = MAX_TILT_DEG) -> float:
    """``tilt_deg``: the target's tilt on the stand, degrees in [0, high]."""
    if isinstance(value, bool) or not isinstance(value, Real) or not 0.0 <= value <= high:
        raise ValueError(f"tilt_deg must be a number of degrees in [0, {high:g}], got {value!r}")
    return float(value)
