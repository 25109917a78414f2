"""A template third-party arcsem plugin (a constant-colour backbone).

The entry point ``arcsem.backbones: constant = "arcsem_plugin_template"`` names this package, which defines the
backbone's two names: ``CONFIG``, its Config dataclass (``config.py``: no torch, read at arcsem's start-up as the
Hydra schema), and ``BACKBONE``, its class (``backbone.py``: imported only when ``backbone=constant`` is used).
"""
from arcsem.lazy import lazy_getattr

__all__ = ["BACKBONE", "CONFIG"]

__getattr__ = lazy_getattr(__name__, {"CONFIG": "config:ConstantConfig", "BACKBONE": "backbone:ConstantBackbone"})
