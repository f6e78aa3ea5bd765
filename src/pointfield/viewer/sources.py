"""What each PATH given to ``pointfield view`` is, and the module that shows it.

===========================================  ======  =================================================================
PATH                                         kind    shown by
===========================================  ======  =================================================================
a cloud or mesh file, any format it reads    cloud   :mod:`pointfield.viewer.clouds`
a splat ``.ply`` (``f_dc_0`` ... ``rot_3``)  splats  :mod:`pointfield.viewer.splats`
a scene folder, or its ``transforms*.json``  scene   :mod:`pointfield.viewer.scenes` (any format ``scene info`` reads)
a splat run folder                           run     :mod:`pointfield.viewer.splats` (+ server render)
a nerf run folder (tiny, nerf, ngp)          run     :mod:`pointfield.viewer.fields`
===========================================  ======  =================================================================

Every PATH is checked before the server starts, so a bad one is the one-line error of every
other command (``pointfield: error: scan.xyz: no such file``).

The modules that show scenes and runs need torch (two seconds to import on a laptop CPU); a
page of clouds does not, so each kind's module is imported when a PATH of that kind is shown
(:data:`SHOWN_BY`), and checking a PATH imports the scene readers only for folders.
"""

from __future__ import annotations

import importlib
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pointfield.clouds.formats.ply import SPLAT_PROPERTIES, is_ply, parse_header
from pointfield.clouds.formats.ply.header import HEADER_LIMIT
from pointfield.clouds.formats.registry import format_of
from pointfield.errors import PointfieldError
from pointfield.viewer.clouds import DEFAULT_MAX_POINTS
from pointfield.viewer.server import DEFAULT_HOST, DEFAULT_PORT, Viewer, start_viewer
from pointfield.volumes.files import is_voxel_file

SHOWN_BY = {
    "cloud": ("pointfield.viewer.clouds", "show_cloud"),
    "splats": ("pointfield.viewer.splats", "show_splat_file"),
    "scene": ("pointfield.viewer.scenes", "show_scene"),
    "run": ("pointfield.viewer.fields", "show_run"),
}
"""Kind -> (module, function) that adds a PATH of that kind to the page."""
KINDS = tuple(SHOWN_BY)
VIEWABLE_TASKS = ("nerf", "splat")


def kind_of(path: str | os.PathLike[str]) -> str:
    """Which of :data:`KINDS` ``path`` is; FileNotFoundError or FormatError when it is none."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or directory")
    if path.is_dir():
        config = path / "config.json"
        if config.is_file():
            try:
                task = json.loads(config.read_text(encoding="utf-8")).get("task")
            except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError) as error:
                raise PointfieldError(f"{config}: cannot read it as a run's config ({error})") from None
            if task not in VIEWABLE_TASKS:
                raise PointfieldError(f"{path}: a {task!r} run has nothing to show in 3D; "
                                      f"the viewer shows nerf and splat runs")
            return "run"
        scene_formats().detect_scene_format(path)  # raises the readers' own error for a non-scene
        return "scene"
    if path.suffix.lower() == ".json":
        scene_formats().detect_scene_format(path)
        return "scene"
    if is_splat_file(path):
        return "splats"
    if is_voxel_file(path):
        return "cloud"  # shown as its voxel centres (viewer/clouds.py)
    format_of(path)  # raises FormatError for a file no cloud reader knows
    return "cloud"


def scene_formats() -> Any:
    """The scene-format registry, imported on first use (it imports torch)."""
    return importlib.import_module("pointfield.scenes.formats.registry")


def is_splat_file(path: Path) -> bool:
    """True for a PLY whose vertices have the splat properties (:data:`SPLAT_PROPERTIES`).

    The header is read by the PLY reader's own parser, so a malformed one is its FormatError.
    """
    with open(path, "rb") as file:
        head = file.read(HEADER_LIMIT)
    if not is_ply(head):
        return False
    vertices = [e for e in parse_header(path, head).elements if e.name == "vertex"]
    return bool(vertices) and set(SPLAT_PROPERTIES) <= {p.name for p in vertices[0].properties}


def unique_names(paths: Sequence[Path]) -> list[str]:
    """A scene-tree name per path: its stem, numbered where two paths share one."""
    names: list[str] = []
    for path in paths:
        stem = "".join(c if c.isalnum() or c in "-_." else "_" for c in (path.stem or path.name)) or "source"
        name, number = stem, 2
        while name in names:
            name, number = f"{stem}-{number}", number + 1
        names.append(name)
    return names


def show(viewer: Viewer, path: Path, kind: str, name: str, *, max_points: int = DEFAULT_MAX_POINTS,
         device: str | None = None) -> Any:
    """Add ``path`` of kind ``kind`` (from :func:`kind_of`) to the page under ``/<name>``; returns its view."""
    if kind not in SHOWN_BY:
        raise ValueError(f"unknown kind {kind!r}; expected one of {', '.join(KINDS)}")
    module, function = SHOWN_BY[kind]
    options = {"cloud": {"max_points": max_points}, "scene": {"max_points": max_points},
               "run": {"device": device}}.get(kind, {})
    return getattr(importlib.import_module(module), function)(viewer, path, name, **options)


def open_viewer(paths: Sequence[str | os.PathLike[str]], *, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                max_points: int = DEFAULT_MAX_POINTS, device: str | None = None,
                on_started: Any = None) -> tuple[Viewer, list[Any]]:
    """Check every path, start the server, then show each path; returns the viewer and the views.

    ``on_started(viewer)`` is called once the server listens, before anything is read, so that
    a browser can load the page while large files are read (the command prints the URL there).
    If showing a path fails, the server is stopped and the error raised.
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise PointfieldError("nothing to view: give at least one PATH")
    kinds = [kind_of(path) for path in paths]
    viewer = start_viewer(host, port)
    try:
        if on_started is not None:
            on_started(viewer)
        views = [show(viewer, path, kind, name, max_points=max_points, device=device)
                 for path, kind, name in zip(paths, kinds, unique_names(paths))]
    except BaseException:
        viewer.close()
        raise
    return viewer, views


def view(paths: Sequence[str | os.PathLike[str]], *, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
         max_points: int = DEFAULT_MAX_POINTS, device: str | None = None, on_started: Any = None) -> None:
    """``pointfield view PATH [PATH ...]``: show every path on one page and serve it until Ctrl-C."""
    viewer, _ = open_viewer(paths, host=host, port=port, max_points=max_points, device=device,
                            on_started=on_started)
    viewer.serve()


__all__ = ["KINDS", "kind_of", "open_viewer", "show", "view"]
