"""Volumes: voxel grids and signed distance fields, the lesson's other explicit and implicit representations.

===================================  =====================================================
:class:`VoxelGrid`                   sparse occupied voxels with per-voxel fields (voxels.py)
:func:`voxelize_cloud` / ``_mesh``   a grid from points, or a mesh's surface or solid
:func:`read_voxels` / ``write``      ``.binvox``, MagicaVoxel ``.vox``, ``.npz`` (files.py)
:class:`SDFGrid`                     signed distances on a grid: trilinear queries, gradients, marching cubes (sdf.py)
:func:`mesh_to_sdf`                  a mesh's SDF, signed by the generalized winding number
:class:`OccupancyMap`                occupied / free / unknown from scans by ray casting, as OctoMap (occupancy.py)
:func:`poisson_surface`              points with normals to a watertight mesh (Poisson, FFT on a grid; poisson.py)
winding numbers, distances           of a triangle soup, clustered as Barill et al. (triangles.py)
===================================  =====================================================
"""

from pointfield.volumes.files import read_voxels, write_voxels
from pointfield.volumes.occupancy import OccupancyMap
from pointfield.volumes.poisson import poisson_surface
from pointfield.volumes.sdf import SDFGrid, mesh_to_sdf
from pointfield.volumes.voxels import (
    VoxelGrid,
    mesh_openness,
    openness_text,
    voxelize_cloud,
    voxelize_mesh,
)

__all__ = [
    "OccupancyMap",
    "SDFGrid",
    "VoxelGrid",
    "mesh_openness",
    "mesh_to_sdf",
    "openness_text",
    "poisson_surface",
    "read_voxels",
    "voxelize_cloud",
    "voxelize_mesh",
    "write_voxels",
]
