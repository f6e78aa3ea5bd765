"""Point-cloud file formats: one module per format, each registering itself on import."""

from pointfield.clouds.formats import e57, las, npy, off, pcd, ply, text, velodyne  # noqa: F401
from pointfield.clouds.formats.registry import Format, format_named, format_of, formats, read, write

__all__ = ["Format", "format_named", "format_of", "formats", "read", "write"]
