"""Vision side of scorbot-gym: pose-manifold estimation and shape recognition.

This package never imports :mod:`scorbot_gym`: images, masks and camera parameters come in,
poses and class labels go out.
"""
