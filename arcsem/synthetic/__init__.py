"""Built-in synthetic SEM scene: a procedural pollen grain with ground truth for every view.

``generate_scene(out_dir, ...)`` writes a dataset in the ``transforms.json`` layout;
``ensure_scene(path=None, ...)`` returns a cached one (generating it once). Modules: ``sdf``
(geometry), ``cameras`` (arcs), ``trace`` (sphere tracing), ``shading`` (SEM contrast), ``albedo``
(colour), ``render`` (views), ``write`` (dataset, PLY), ``colmap``, ``sheet`` (contact sheet),
``cache``; further specimens: ``diatom`` (a frustule), ``parts`` (coloured by part).
"""
from .cache import ensure_scene
from .write import SceneParams, generate_scene, reference_sets

__all__ = ["SceneParams", "ensure_scene", "generate_scene", "reference_sets"]
