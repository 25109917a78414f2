"""Backbone plugins (one folder each) and the shared Gaussian machinery."""
__all__: list[str] = []
