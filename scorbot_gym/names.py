"""The names of the package's swappable components, as plain constants.

The command line offers these as option choices. Listing them (``--help``) or rejecting a bad
one must not import what they name: the simulator (MuJoCo, dm_control), OpenCV, scikit-learn
and the learners take seconds to import (issue 35). So the names live here, in a module that
imports nothing, and each registry either takes its names from here or is checked against them
by ``tests/test_cli_parsing.py``: a component added to a registry and not here (or the other
way round) fails that test instead of going missing from the command line.
"""

from __future__ import annotations

#: who acts in ``scorbot-gym rollout`` (besides a policy or training-run folder);
#: :mod:`scorbot_gym.evaluation.rollout` takes them from here
POLICIES = (
    "scripted",
    "random",
    "rl",
    "learned",
    "finetuned",
    "learned_grasp_frame",
    "finetuned_grasp_frame",
    "rl_grasp_frame",
    "rl_scratch",
)
#: the pose sources :mod:`scorbot_gym.perception.registry` registers itself (sorted)
POSE_SOURCES = (
    "constant",
    "largest_blob",
    "manifold",
    "manifold_clutter",
    "noisy_oracle",
    "occluded_oracle",
    "oracle",
    "oracle_position",
    "random_blob",
)
#: short pose-source names the command line accepts, and the registered source each stands for
POSE_ALIASES = {"noisy": "noisy_oracle"}
#: what an image-based pose source is told of the object (``make_env``'s ``identity``):
#: ``recognize`` (it recognises the object; no privileged input) or ``given`` (the true class)
IDENTITIES = ("recognize", "given")

#: the fixed cameras, in the order of :data:`scorbot_gym.sim.scene.DEFAULT_CAMERAS`
FIXED_CAMERAS = ("top", "side", "overview")
#: cameras carried by the arm: their extrinsics change with every step (the others are fixed);
#: :mod:`scorbot_gym.sim.simulation` takes them from here
MOVING_CAMERAS = ("eye_in_hand",)

#: :func:`scorbot_gym.perception.segmenters.segmenter_names` (sorted)
SEGMENTERS = ("background", "depth", "privileged")
#: :mod:`scorbot_gym.perception.splitters` takes them from here (``none``: blobs left whole)
SPLITTERS = ("none", "keypoints", "distance")
#: :func:`scorbot_gym.perception.support.support_names` (``none``: no prior)
SUPPORTS = ("table", "table_memory", "none")
#: :mod:`scorbot_gym.perception.calibration` takes them from here (``none``: the cameras as
#: calibrated; ``arm``: re-calibrated from the arm's silhouette while the episode runs)
CALIBRATIONS = ("none", "arm")
#: :mod:`scorbot_gym.perception.recognizers` takes them from here
RECOGNIZERS = ("flr", "appearance", "flr+appearance")
#: :func:`scorbot_gym.perception.motion.motion_names` (sorted)
MOTIONS = ("silhouette",)
#: :data:`scorbot_gym.tasks.disturbance.DISTURBANCES`, in its order
DISTURBANCES = ("push", "slide")
#: :func:`scorbot_gym.data.protocols.protocol_names`, in its order
PROTOCOLS = (
    "top-resting",
    "side-turntable",
    "overview",
    "tilted",
    "sparse-headings",
    "cross-camera",
    "clutter",
)
