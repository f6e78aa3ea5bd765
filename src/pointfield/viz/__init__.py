"""Pictures: PNG renders of point clouds and contact sheets of several."""

from pointfield.viz.render import guess_up_axis, image_grid, render_cloud, render_file, save_image

__all__ = ["guess_up_axis", "image_grid", "render_cloud", "render_file", "save_image"]
