"""SEM image series: reading images and vendor metadata, cropping data bars, the inspection table.

``read_series(folder)`` reads every image of a folder (:mod:`.image`, :mod:`.metadata`), checks that they
share one size, finds one crop for all of them (:mod:`.crop`: data bar, dead borders) and returns a
:class:`~arcsem.sem.series.Series`; ``inspect_table(series)`` is what ``arcsem-calibrate --inspect`` prints.
"""
from .crop import Crop, detect_crop
from .image import SemImage, read_sem_image
from .metadata import SemMeta
from .series import Series, inspect_table, read_series

__all__ = ["Crop", "SemImage", "SemMeta", "Series", "detect_crop", "inspect_table", "read_sem_image", "read_series"]
