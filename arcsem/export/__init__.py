"""Products of a finished run folder: orbit videos (``render``: ``stage=render``) and the ``arcsem-export``
command (mesh and viewer folder on demand: :mod:`arcsem.cli.export`); both open the run with :mod:`arcsem.runs`."""

__all__: list[str] = []
