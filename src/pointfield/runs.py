"""``load_run``: any run folder pointfield wrote, opened as the :class:`~pointfield.training.Run` of its kind.

======================  ================================================  ======================================
``config.json`` task    opened as                                         what it does besides ``metrics``
======================  ================================================  ======================================
classify, segment       :class:`~pointfield.clouds.run.CloudRun`          ``evaluate(data)``, ``predict(files)``
segment-scenes          :class:`~pointfield.clouds.scene_tasks.SceneRun`  ``evaluate(data)``, ``predict(files)``
nerf (tiny, nerf, ngp)  :class:`~pointfield.fields.run.FieldRun`          ``render(cameras)``, ``evaluate()``
splat                   :class:`~pointfield.splats.run.SplatRun`          ``render(cameras)``, ``evaluate()``
======================  ================================================  ======================================

Example::

    import pointfield
    run = pointfield.load_run("runs/lego-ngp")
    views = run.render(run.scene.cameras[:2], outputs=("rgb", "depth", "opacity"))
"""

from __future__ import annotations

import os

from pointfield.clouds.run import CloudRun
from pointfield.clouds.scene_tasks import SceneRun
from pointfield.fields.run import FieldRun
from pointfield.splats.run import SplatRun
from pointfield.training.lifecycle import open_run
from pointfield.training.run import Run

RUN_CLASSES: tuple[type[Run], ...] = (CloudRun, SceneRun, FieldRun, SplatRun)


def load_run(path: str | os.PathLike[str], device: str | None = None) -> Run:
    """The run in folder ``path``, its model restored from the last checkpoint, on ``device``.

    Works for finished runs and for runs still training or killed (their last checkpoint).
    A folder that is not a run, or a checkpoint that does not match the run's config, raises
    :class:`~pointfield.PointfieldError` saying so.
    """
    return open_run(RUN_CLASSES, path, device)
