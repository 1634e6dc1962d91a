"""Generated assets: procedural textures and mesh preprocessing (nothing is downloaded)."""
