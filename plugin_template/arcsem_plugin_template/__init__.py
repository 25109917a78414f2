"""A template third-party arcsem plugin (a constant-colour backbone)."""
__all__: list[str] = []
