"""Camera poses for a user's own photos or video, by structure from motion (pycolmap), on the CPU.

::

    from pointfield.scenes.sfm import pose_images, pose_video
    report = pose_images("my_photos", "my_scene")        # or: pointfield scene from-images
    report = pose_video("walk.mp4", "my_scene", frames=150)
    print(report.format())

The scene written is the nerfstudio layout (transforms.json, images/, images_2/4/8,
points3D.ply, colmap/sparse/0, report.json, cameras.png); see :mod:`.pipeline` for the stages
and docs/photos.md for the guide.
"""

from pointfield.scenes.sfm.errors import PosingError
from pointfield.scenes.sfm.photos import Photo, gather_photos
from pointfield.scenes.sfm.pipeline import (
    PosingOptions,
    PosingReport,
    pose_images,
    pose_video,
)
from pointfield.scenes.sfm.video import extract_frames, sharpness

__all__ = [
    "Photo",
    "PosingError",
    "PosingOptions",
    "PosingReport",
    "extract_frames",
    "gather_photos",
    "pose_images",
    "pose_video",
    "sharpness",
]
