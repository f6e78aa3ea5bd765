"""The error of posing photos: what was wrong with them and what to try."""

from __future__ import annotations

from pointfield.scenes.scene import SceneError


class PosingError(SceneError):
    """Photos or a video cannot be posed: too few images, unreadable files, nothing in common.

    The message names the problem (and the file, where one is to blame) and what to try.
    """
