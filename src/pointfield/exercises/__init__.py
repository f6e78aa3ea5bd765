"""The lesson's exercises, reproduced as reports a user can regenerate.

- :mod:`~pointfield.exercises.tinynerf` (``pointfield nerf exercise``): TinyNeRF trained on
  rendered views of a coloured cube -- the loss at epoch 1, 10 and 100, and the epoch at which
  its views become recognisable.

The other two exercises are tests that read as their statements:
``tests/clouds/models/test_pointnet.py`` (PointNet is permutation-invariant) and
``tests/scenes/test_cameras.py`` (a ray for every pixel of an H x W image from intrinsics and pose).
"""
