"""Calibration of SEM series: orthographic cameras from the images and the microscope's stage angles.

``calibrate(series, options)`` (:mod:`.pipeline`) runs features (:mod:`.features`), pairwise matching verified
by the affine fundamental matrix (:mod:`.matching`), tracks (:mod:`.tracks`), initial cameras from stage
angles (:mod:`.init`) or affine factorisation (:mod:`.factorization`), sub-pixel refinement (:mod:`.refine`),
robust bundle adjustment (:mod:`.bundle`), the world frame (:mod:`.frame`) and specimen masks
(:mod:`.masks`); :mod:`.write` and :mod:`.report` write the dataset folder. Method: docs/calibration.md.
"""
from .bundle import OrthoViews, StageModel, bundle_adjust
from .pipeline import Calibration, CalibrationOptions, calibrate

__all__ = ["Calibration", "CalibrationOptions", "OrthoViews", "StageModel", "bundle_adjust", "calibrate"]
