"""Hydra config tree (pkg://arcsem.conf)."""
