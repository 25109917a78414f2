"""Products of a finished run folder: open it again (``runs``), orbit videos (``render``: ``stage=render``),
and the ``arcsem-export`` command (mesh and viewer folder on demand: :mod:`arcsem.cli.export`)."""
from .runs import RunModel, find_checkpoint, has_colour, load_run

__all__ = ["RunModel", "find_checkpoint", "has_colour", "load_run"]
