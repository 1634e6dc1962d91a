"""Rendered, labelled data for the vision side: pose views and silhouettes, cached on disk."""

import os
from pathlib import Path


def default_cache_dir() -> Path:
    """Where rendered views, silhouettes, fitted models and derived object geometry are cached:
    ``$SCORBOT_GYM_CACHE``, else ``~/.cache/scorbot-gym``. Defined here, not in ``views``, so
    that finding it imports nothing else (an env looks it up at ``make``)."""
    env = os.environ.get("SCORBOT_GYM_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "scorbot-gym"
