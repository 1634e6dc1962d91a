"""Rendered, labelled data for the vision side: pose views and silhouettes, cached on disk."""
