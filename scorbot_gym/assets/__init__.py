"""Generated assets: procedural textures and mesh preprocessing (nothing is downloaded), and the
held-out objects outside the catalogue (:mod:`scorbot_gym.assets.heldout_objects`)."""
