"""pointfield: a Python toolkit for 3D vision — point clouds, radiance fields, Gaussian splats.

The two functions most people need first::

    import pointfield
    cloud = pointfield.read("scan.pcd")          # any supported format
    pointfield.write("scan.ply", cloud)          # fields preserved, written atomically
"""

from pointfield.clouds import Mesh, PointCloud, Records, read, write  # noqa: E402
from pointfield.errors import FormatError, PointfieldError  # noqa: E402
from pointfield.version import __version__  # noqa: E402

__all__ = [
    "FormatError",
    "Mesh",
    "PointCloud",
    "PointfieldError",
    "Records",
    "__version__",
    "read",
    "write",
]
