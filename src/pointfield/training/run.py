"""The run directory -- everything one training run writes, in one folder -- and a run opened for use.

::

    RUN/
      config.json          what was trained on what, with which settings (written first)
      metrics.jsonl        one JSON object per finished epoch (and one for an epoch cut short)
      metrics.json         the final scores
      checkpoints/last.pt  the latest checkpoint (atomic; --resume continues from it)
      *.png                pictures the task draws: training curves, confusion matrix, ...

Every file is replaced atomically, so a run killed at any moment leaves each file either as it
was or as it was meant to be, never half-written. The JSON files are strict JSON, which every
parser reads (JavaScript's too): a number that is not finite -- a score that does not exist,
such as the opacity error of images without alpha, or SSIM of views under 11 pixels -- is
written as ``null`` (:func:`to_json`).
"""

from __future__ import annotations

import json
import math
import os
import warnings
from pathlib import Path
from typing import Any, ClassVar

import torch
from torch import nn

from pointfield.atomic import atomic_path
from pointfield.errors import PointfieldError


class RunDirectory:
    """Paths and writers of one run's folder."""

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)
        self.config = self.path / "config.json"
        self.metrics_log = self.path / "metrics.jsonl"
        self.final_metrics = self.path / "metrics.json"
        self.checkpoint = self.path / "checkpoints" / "last.pt"

    def create(self, resume: bool) -> None:
        """Make the folder; refuse to start a new run over an old one unless resuming it.

        Resuming also removes the temporary files a killed run may have left mid-write (the
        files they were to replace are intact: writes are atomic).
        """
        if not resume and (self.config.exists() or self.checkpoint.exists()):
            raise PointfieldError(
                f"{self.path} already holds a run: pass resume=True to continue it, or choose another out",
                command_line=f"{self.path} already holds a run: pass --resume to continue it, or choose another --out",
            )
        if self.path.exists() and not self.path.is_dir():
            raise PointfieldError(f"{self.path} exists and is not a folder")
        self.checkpoint.parent.mkdir(parents=True, exist_ok=True)
        if resume:
            for leftover in self.path.rglob(".*.tmp*"):
                leftover.unlink(missing_ok=True)

    def exists(self) -> bool:
        return self.config.is_file()

    def read_config(self) -> dict[str, Any]:
        if not self.config.is_file():
            raise PointfieldError(f"{self.path}: not a run folder (no config.json)")
        return read_json(self.config)

    def write_config(self, config: dict[str, Any]) -> None:
        write_json(self.config, config)

    def write_metrics_log(self, records: list[dict[str, Any]]) -> None:
        """Rewrite ``metrics.jsonl`` whole: one line per record (cheap, and never torn)."""
        lines = "".join(to_json(record) + "\n" for record in records)
        with atomic_path(self.metrics_log) as tmp:
            tmp.write_text(lines, encoding="utf-8")

    def read_metrics_log(self) -> list[dict[str, Any]]:
        if not self.metrics_log.is_file():
            return []
        return [json.loads(line) for line in self.metrics_log.read_text().splitlines() if line]

    def write_final_metrics(self, metrics: dict[str, Any]) -> None:
        write_json(self.final_metrics, metrics)


def to_json(data: Any, indent: int | None = None) -> str:
    """``data`` as strict JSON: NaN and infinities (a score that does not exist) become ``null``.

    >>> to_json({"psnr": 21.5, "opacity_error": float("nan"), "views": [1.0, float("inf")]})
    '{"psnr": 21.5, "opacity_error": null, "views": [1.0, null]}'
    """
    return json.dumps(_finite_or_none(data), indent=indent, allow_nan=False)


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite_or_none(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(item) for item in value]
    return value


def write_json(path: Path, data: Any) -> None:
    """``data`` as strict, indented JSON (:func:`to_json`), written atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(to_json(data, indent=2) + "\n", encoding="utf-8")


def read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise PointfieldError(f"{path}: cannot read it as JSON ({error})") from None


class Run:
    """A trained run opened for use: its folder, settings, history, scores and model.

    Every kind of run (:func:`pointfield.load_run` opens any of them) has ``path``,
    ``config`` (its ``config.json``), ``task`` and ``model_name`` (what was trained),
    ``history`` (``metrics.jsonl``), ``metrics`` (``metrics.json``; empty while a run is still
    unfinished), ``device`` and ``module`` (the trained model, in evaluation mode). Each kind
    adds what it can do: a cloud run predicts, a scene run renders any camera.
    """

    tasks: ClassVar[tuple[str, ...]]
    """The ``config["task"]`` values this class opens."""

    def __init__(self, directory: RunDirectory, config: dict[str, Any], module: nn.Module, device: torch.device):
        self.directory = directory
        self.config = config
        self.module = module
        self.device = device

    @property
    def path(self) -> Path:
        return self.directory.path

    @property
    def task(self) -> str:
        return self.config["task"]

    @property
    def model_name(self) -> str:
        return str(self.config.get("model", self.task))

    @property
    def history(self) -> list[dict[str, Any]]:
        return self.directory.read_metrics_log()

    @property
    def metrics(self) -> dict[str, Any]:
        final = self.directory.final_metrics
        return read_json(final) if final.is_file() else {}

    @property
    def finished(self) -> bool:
        """Whether training ran to its end and wrote ``metrics.json``: not a run interrupted or still running."""
        return self.directory.final_metrics.is_file()

    def warn_if_unfinished(self, use: str) -> None:
        """A warning that ``use`` ("predictions come from") the last checkpoint of an unfinished run."""
        if self.finished:
            return
        whole = [record for record in self.history if not record.get("partial")]
        done = f"epoch {whole[-1]['epoch']}" if whole else "no whole epoch"
        planned = f" of {self.config['epochs']}" if "epochs" in self.config else ""
        warnings.warn(f"{self.path} is an unfinished run (it stopped after {done}{planned} and has no "
                      f"metrics.json): {use} its last checkpoint; resume the run to finish training", stacklevel=3)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r}, task={self.task!r}, model={self.model_name!r}, device={self.device})"
