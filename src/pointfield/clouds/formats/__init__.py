"""Point-cloud file formats: one module per format, each registering itself on import."""

from pointfield.clouds.formats import (  # noqa: F401  (each registers itself)
    e57,
    las,
    meshes,
    npy,
    npz,
    off,
    pcd,
    ply,
    ptx,
    text,
    velodyne,
)
from pointfield.clouds.formats.registry import (
    Format,
    format_named,
    format_of,
    formats,
    read,
    write,
)

__all__ = ["Format", "format_named", "format_of", "formats", "read", "write"]
