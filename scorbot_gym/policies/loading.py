"""Load any saved policy folder by what its ``policy.json`` says it is.

``"algo": "imitation"`` → :class:`~scorbot_gym.policies.imitation.ImitationPolicy` (numpy MLP,
stand-alone); ``"pixel_imitation"`` → :class:`~scorbot_gym.policies.pixel.PixelPolicy` (CNN on
the top camera image, no pose estimate); ``sac``/``tqc``/``ppo`` →
:class:`~scorbot_gym.policies.sb3.SB3Policy`. The names ``rl`` (the shipped residual) and
``learned`` (the shipped stand-alone imitation policy), ``finetuned`` (that policy after
RL fine-tuning), ``learned_grasp_frame`` (``learned``'s recipe reading the object's grasp
frame instead of its class), ``finetuned_grasp_frame`` (it after the same fine-tune) and
``rl_grasp_frame`` (the residual reading the grasp frame) and ``rl_scratch`` (SAC from
scratch, no controller and no demonstrations, reading the grasp frame) stand for the policies
in the package (:data:`SHIPPED`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from scorbot_gym.policies.imitation import (
    ALGO,
    SHIPPED_FINETUNED_POLICY,
    SHIPPED_GRASP_FRAME_FINETUNED_POLICY,
    SHIPPED_GRASP_FRAME_POLICY,
    SHIPPED_LEARNED_POLICY,
)
from scorbot_gym.policies.sb3 import (
    SHIPPED_GRASP_FRAME_RESIDUAL,
    SHIPPED_POLICY,
    SHIPPED_SCRATCH_POLICY,
    read_policy_json,
)

PIXEL_ALGO = "pixel_imitation"  # scorbot_gym.policies.pixel.ALGO, without importing cv2/torch

SHIPPED = {
    "rl": SHIPPED_POLICY,
    "learned": SHIPPED_LEARNED_POLICY,
    "finetuned": SHIPPED_FINETUNED_POLICY,
    "learned_grasp_frame": SHIPPED_GRASP_FRAME_POLICY,
    "finetuned_grasp_frame": SHIPPED_GRASP_FRAME_FINETUNED_POLICY,
    "rl_grasp_frame": SHIPPED_GRASP_FRAME_RESIDUAL,
    "rl_scratch": SHIPPED_SCRATCH_POLICY,
}


def load_policy(path: str | Path, checkpoint: str = "best") -> Any:
    """A saved policy (folder, ``rl`` / ``learned`` / ``finetuned``, or a ``scorbot-gym train``
    run folder whose ``checkpoint``, ``best`` or ``last``, is loaded), with one-line errors for
    bad files."""
    from scorbot_gym.rl.runs import policy_dir

    if str(path) in SHIPPED:
        path = SHIPPED[str(path)]
    else:
        path = Path(path)
        path = policy_dir(path.parent if path.is_file() else path, checkpoint)
    meta_path = path / "policy.json"
    algo = read_policy_json(meta_path).get("algo") if meta_path.is_file() else None
    if algo == PIXEL_ALGO:
        from scorbot_gym.policies.pixel import PixelPolicy

        return PixelPolicy.load(path)
    sb3_files = ("model.safetensors", "model.zip")  # the SB3 format, and the refused old one
    imitation = (path / "weights.npz").is_file() and not any(
        (path / f).is_file() for f in sb3_files
    )
    if imitation or algo == ALGO:
        from scorbot_gym.policies.imitation import ImitationPolicy

        return ImitationPolicy.load(path)
    from scorbot_gym.policies.sb3 import SB3Policy

    return SB3Policy.load(path)


def uses_scripted_controller(policy: Any) -> bool:
    """Whether a loaded policy runs the scripted controller inside it at test time."""
    flag = getattr(policy, "uses_scripted_controller", None)
    if flag is not None:
        return bool(flag)
    meta = getattr(policy, "meta", {}) or {}
    return bool(meta.get("uses_scripted_controller", meta.get("residual") is not None))
