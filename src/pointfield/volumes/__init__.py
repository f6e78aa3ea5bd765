"""Volumes: voxel grids and signed distance fields, the lesson's other explicit and implicit representations.

=================================  =====================================================
:class:`VoxelGrid`                 sparse occupied voxels with per-voxel fields (voxels.py)
:func:`voxelize_cloud` / ``_mesh`` a grid from points, or a mesh's surface or solid
:func:`read_voxels` / ``write``    ``.binvox``, MagicaVoxel ``.vox``, ``.npz`` (files.py)
=================================  =====================================================
"""

from pointfield.volumes.files import read_voxels, write_voxels
from pointfield.volumes.voxels import (
    VoxelGrid,
    mesh_openness,
    openness_text,
    voxelize_cloud,
    voxelize_mesh,
)

__all__ = ["VoxelGrid", "mesh_openness", "openness_text", "read_voxels", "voxelize_cloud", "voxelize_mesh",
           "write_voxels"]
