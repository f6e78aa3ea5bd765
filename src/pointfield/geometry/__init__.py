"""Geometry out of any trained scene model: depth back-projected into point clouds (meshes to come).

::

    from pointfield.geometry import export_cloud
    export_cloud("runs/lego-ngp", "lego.ply", points=200_000)     # or: pointfield nerf export RUN --cloud

Everything here renders through the one run interface (``load_run(path).render(cameras)``), so
TinyNeRF, NeRF, the hash-grid field and splats give geometry the same way.
"""

from pointfield.geometry.clouds import backproject, clean_cloud, cloud_from_views, export_cloud

__all__ = ["backproject", "clean_cloud", "cloud_from_views", "export_cloud"]
