"""Hydra configs of this plugin package (added to the search path by hydra_plugins/)."""
