"""Geometry out of any trained scene model: rendered depth as point clouds and TSDF meshes; density meshes of fields.

::

    from pointfield.geometry import export_cloud, export_mesh
    export_cloud("runs/lego-ngp", "lego.ply", points=200_000)     # or: pointfield nerf export RUN --cloud
    export_mesh("runs/lego-ngp", "lego.glb", resolution=256)      # or: pointfield nerf export RUN --mesh
    export_mesh("runs/lego-ngp", "lego.ply", method="density")    # or: ... --mesh lego.ply --method density

Everything here renders through the one run interface (``load_run(path).render(cameras)``), so
TinyNeRF, NeRF, the hash-grid field and splats give geometry the same way. A field run of a
bounded scene also has a density at every point, which :func:`mesh_from_density` meshes directly.
"""

from pointfield.geometry.clouds import (
    backproject,
    clean_cloud,
    cloud_from_views,
    export_cloud,
)
from pointfield.geometry.density import mesh_from_density
from pointfield.geometry.meshes import export_mesh, mesh_from_volume, write_mesh
from pointfield.geometry.tsdf import TSDFVolume

__all__ = [
    "TSDFVolume",
    "backproject",
    "clean_cloud",
    "cloud_from_views",
    "export_cloud",
    "export_mesh",
    "mesh_from_density",
    "mesh_from_volume",
    "write_mesh",
]
