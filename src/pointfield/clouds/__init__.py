"""Explicit 3D: point clouds, the meshes they come from, and their file formats."""

from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats import read, write
from pointfield.clouds.mesh import Mesh

__all__ = ["Mesh", "PointCloud", "Records", "read", "write"]
