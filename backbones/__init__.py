"""Backbone plugins (one folder each), the shared Gaussian machinery (``gaussians/``) and what every backbone
may use (``sh.py``: spherical harmonics)."""
__all__: list[str] = []
