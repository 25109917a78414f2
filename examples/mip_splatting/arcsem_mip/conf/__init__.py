"""Hydra configs of the plugin: backbone/gs3d_mip, variant/gs3d_mip (a grayscale-comparison row), tuning."""
