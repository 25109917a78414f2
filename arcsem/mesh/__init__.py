"""Meshes of trained models: TSDF fusion of rendered depth (``tsdf``), export (``extract``) and the
Chamfer distance to the built-in scene's ground-truth surface (``groundtruth``)."""
from .extract import MeshConfig, export_mesh, mesh_config

__all__ = ["MeshConfig", "export_mesh", "mesh_config"]
