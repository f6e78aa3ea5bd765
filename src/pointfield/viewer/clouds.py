"""A point cloud or mesh file in the browser: decimated past a budget, coloured by any field.

:func:`show_cloud` reads the file with :func:`pointfield.read` (any format it reads) and adds
it to the page under ``/<name>``:

- at most ``max_points`` points, drawn uniformly at random when the file has more, and the
  panel says so ("showing 2,000,000 of 38,412,905 points");
- a *colour by* dropdown: ``rgb`` (the file's colours), ``height``, and every other field,
  coloured as ``pointfield cloud render`` colours them (:func:`pointfield.viz.render.point_colours`),
  except classification (the ASPRS class colours) and vectors other than normals (their length);
- a point-size slider, the bounding box and axes (each can be hidden);
- LAS / UTM coordinates recentred for display (:meth:`~pointfield.viewer.server.Viewer.recentre`),
  while the panel reports real coordinates: the bounds, and the point last clicked with its fields.

A mesh shows its faces (vertex-coloured by the same dropdown), quadric-decimated to
``max_points`` faces when it has more.

A LAZ file larger than the budget is first shown as a quick *preview* -- the first points of
every compressed chunk, which lazrs can decompress without the rest of the chunk -- while the
whole file is read; the decimated cloud then replaces it. LAZ decompression is most of the
time a large scan takes to open (about 3.5 s for 10 million points on two cores), and the
preview needs a small part of it (:data:`PREVIEW_FRACTION`).
"""

from __future__ import annotations

import ctypes
import math
import multiprocessing
import os
import signal
import sys
import threading
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import fast_simplification
import laspy
import matplotlib
import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.las.layout import check_layout, check_laz, is_las
from pointfield.clouds.formats.las.reader import cloud_parts
from pointfield.clouds.formats.registry import read
from pointfield.clouds.mesh import Mesh
from pointfield.clouds.ops import random_sample
from pointfield.clouds.sensor import SensorView, sensor_view
from pointfield.errors import FormatError, PointfieldError
from pointfield.viewer.server import Viewer
from pointfield.viz.render import normalised_colours, point_colours
from pointfield.volumes.files import is_voxel_file, read_voxels

DEFAULT_MAX_POINTS = 2_000_000
WORKER_ABOVE_BYTES = 16 * 2**20
"""Files larger than this are read in a worker process (:meth:`CloudView.load`)."""
WORKER_NICENESS = 10
PREVIEW_FRACTION = 64
"""The LAZ preview decompresses about ``max_points / PREVIEW_FRACTION`` points (31,250 of the
default budget): the fewer, the sooner a browser drawing in software shows them. The first frame
``python benchmarks/bench_viewer.py`` measures (a 10 M-point LAZ) took 5.59 s with 125,000 preview
points (at 86df814) and 3.36 s with 31,250 (at e84ddb1)."""
UP = np.array([0.0, 0.0, 1.0])
"""Height is z, as the page's camera starts (LAS, E57 and most scans are z-up)."""
ASPRS_CLASS_COLOURS = {
    0: (160, 160, 160), 1: (190, 190, 190), 2: (166, 118, 60), 3: (140, 200, 90), 4: (70, 160, 60),
    5: (30, 110, 40), 6: (220, 80, 60), 7: (255, 0, 255), 8: (255, 220, 0), 9: (50, 120, 230),
    10: (120, 120, 120), 11: (70, 70, 70), 12: (255, 160, 0), 13: (255, 255, 120), 14: (255, 200, 80),
    15: (200, 200, 255), 16: (180, 120, 255), 17: (0, 200, 200), 18: (255, 0, 0),
}
"""LAS classification codes (ASPRS LAS 1.4, table 17) -> colours: ground brown, vegetation green,
building red, water blue; other codes take a colour from the tab20 map."""


@dataclass
class Prepared:
    """What the page shows of a file, in real coordinates: about ``max_points`` points (or a
    mesh's vertices and triangles) with their fields, the file's count and bounds."""

    points: np.ndarray
    fields: dict[str, np.ndarray]
    total: int
    low: np.ndarray
    high: np.ndarray
    format: str = ""
    faces: np.ndarray | None = None
    preview: bool = False
    sensor: SensorView | None = None
    """Where the file says the cloud was seen from (:func:`~pointfield.clouds.sensor.sensor_view`):
    the page's camera starts there."""

    @property
    def count(self) -> int:
        return len(self.faces) if self.faces is not None else len(self.points)


def prepare(cloud: PointCloud, budget: int, *, total: int | None = None, preview: bool = False,
            seed: int = 0) -> Prepared:
    """The part of ``cloud`` the page shows: :func:`decimate`-d points without NaN, or a decimated mesh."""
    points = np.asarray(cloud.points)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN cloud: bounds at zero
        low, high = np.nan_to_num(np.nanmin(points, axis=0)), np.nan_to_num(np.nanmax(points, axis=0))
    kind = cloud.metadata.get("format", "")
    if isinstance(cloud, Mesh) and len(cloud.faces):
        vertices, faces, fields = mesh_for_display(cloud, budget)
        return Prepared(vertices, fields, len(cloud.triangles()), low, high, kind, faces, preview)
    keep = decimate(len(points), budget, seed)
    index = np.arange(len(points)) if keep is None else keep
    index = index[np.all(np.isfinite(points[index]), axis=1)]
    fields = {name: np.asarray(values)[index] for name, values in cloud.fields.items()
              if np.asarray(values).shape[:1] == points.shape[:1]}
    return Prepared(points[index], fields, len(points) if total is None else total, low, high, kind, None, preview,
                    sensor_view(cloud))


def read_prepared(path: Path, budget: int) -> Prepared | str:
    """Read ``path`` and :func:`prepare` it; an error comes back as its one-line message.

    Runs in a worker process for large files (see :meth:`CloudView.load`), whence pointfield's
    errors, whose constructors take two arguments, would not unpickle.
    """
    try:
        cloud = read_voxels(path).to_cloud() if is_voxel_file(path) else read(path)
        if not isinstance(cloud, PointCloud):
            raise FormatError(path, "has no x, y, z coordinates to show")
        return prepare(cloud, budget)
    except PointfieldError as error:
        return str(error)


def start_worker(viewer_pid: int) -> None:
    """Initializer of the process that reads a large file: a lower priority, and gone with the viewer.

    A viewer killed while the worker sends its result back would leave the worker blocked on the
    pipe for ever (it holds the pipe's other end too, inherited through the fork), with the cloud
    in its memory: on Linux the kernel kills it when the viewer dies (``PR_SET_PDEATHSIG``).
    """
    os.nice(WORKER_NICENESS)
    if sys.platform.startswith("linux"):
        pr_set_pdeathsig = 1
        ctypes.CDLL(None).prctl(pr_set_pdeathsig, signal.SIGKILL)
        if os.getppid() != viewer_pid:  # the viewer died before the line above
            os._exit(1)


def decimate(count: int, budget: int, seed: int = 0) -> np.ndarray | None:
    """Indices (in file order) of ``budget`` of ``count`` points drawn uniformly without
    replacement (:func:`pointfield.clouds.ops.random_sample`); None when all fit."""
    return None if count <= budget else np.sort(random_sample(count, budget, np.random.default_rng(seed)))


def colour_modes(fields: dict[str, np.ndarray]) -> list[str]:
    """What a cloud can be coloured by: ``rgb`` (when it has colours), ``height``, then each field."""
    modes = ["rgb"] if "colors" in fields else []
    modes.append("height")
    for name, values in fields.items():
        if name != "colors" and values.ndim in (1, 2) and values.dtype.kind in "uifb":
            modes.append(name)
    return modes


def colours_for(mode: str, points: np.ndarray, fields: dict[str, np.ndarray]) -> np.ndarray:
    """``(n, 3)`` uint8 colours of every point for colour mode ``mode`` (one of :func:`colour_modes`).

    ``pointfield cloud render``'s colours (:func:`~pointfield.viz.render.point_colours`, height
    along :data:`UP`), except classification, in the ASPRS class colours, and vector fields other
    than normals, by their length.
    """
    if mode == "rgb":
        return as_uint8(normalised_colours(fields["colors"]))
    values = fields.get(mode)
    if mode == "classification" and values.ndim == 1:
        return class_colours(values)
    vector = values is not None and values.ndim == 2 and values.shape[1] > 1
    if vector and not (mode == "normals" and values.shape[1] == 3):
        mode, fields = "length", {"length": np.linalg.norm(values.astype(np.float64), axis=1)}
    return as_uint8(point_colours(mode, points, fields, UP))


def as_uint8(rgb: np.ndarray) -> np.ndarray:
    """``(n, 3)`` colours in [0, 1] as the uint8 the browser takes."""
    return np.round(np.asarray(rgb) * 255).astype(np.uint8)


def class_colours(codes: np.ndarray) -> np.ndarray:
    """Classification codes as colours: :data:`ASPRS_CLASS_COLOURS`, tab20 for the rest."""
    table = (matplotlib.colormaps["tab20"](np.arange(256) % 20)[:, :3] * 255).astype(np.uint8)
    for code, colour in ASPRS_CLASS_COLOURS.items():
        table[code] = colour
    return table[np.asarray(codes).astype(np.int64) % 256]


def laz_preview(path: Path, budget: int) -> tuple[PointCloud, int] | None:
    """About ``budget`` points of a chunked LAZ file, quickly: the first points of every chunk.

    Returns the preview cloud (points and every field, as :func:`pointfield.read` gives them)
    and the file's point count; None for files that are not chunked
    LAZ, or not larger than ``budget``. The header and chunk table are checked first, as
    :func:`pointfield.read` checks them (:mod:`pointfield.clouds.formats.las.layout`).
    """
    size = path.stat().st_size
    with open(path, "rb") as file:
        if not is_las(file.read(4)):
            return None
        file.seek(0)
        layout = check_layout(path, file, size)
        if not layout.compressed or layout.point_count <= budget:
            return None
        if check_laz(path, file, layout, size) is not laspy.LazBackend.LazrsParallel:
            return None  # a single chunk: nothing to gain
        file.seek(0)
        reader = laspy.LasReader(file, closefd=False, laz_backend=laspy.LazBackend.Lazrs)
        chunk = reader.point_source.vlr.chunk_size()
        count = layout.point_count
        if chunk >= count or chunk == 2**32 - 1:  # variable-sized chunks (COPC): no fixed starts
            return None
        starts = range(0, count, chunk)
        take = max(1, math.ceil(budget / len(starts)))
        pieces = []
        for start in starts:
            reader.seek(start)
            pieces.append(reader.read_points(min(take, count - start)))
    # Every field, as pointfield.read gives it (the page's colour-by list then stays the same).
    points, fields = cloud_parts(np.concatenate([piece.array for piece in pieces]), reader.header, path)
    return PointCloud(points, fields), count


class CloudView:
    """One cloud or mesh on the page: its nodes and its panel folder (see the module doc)."""

    def __init__(self, viewer: Viewer, path: Path, name: str, max_points: int = DEFAULT_MAX_POINTS):
        self.viewer = viewer
        self.path = path
        self.name = name
        self.max_points = max_points
        self.shown: Prepared | None = None
        self.display = np.zeros((0, 3), np.float32)
        """``shown.points`` in display coordinates (less the viewer's origin), float32 as the browser draws them."""
        self.node: Any = None
        self.lock = threading.RLock()  # setting a control's value from here runs its callback
        gui = viewer.server.gui
        self.folder = gui.add_folder(name)
        with self.folder:
            self.status = gui.add_markdown(f"reading {path.name} ...")
            self.colour_by = gui.add_dropdown("colour by", ["height"])
            self.point_size = gui.add_slider("point size", min=0.01, max=1.0, step=0.01, initial_value=0.1)
            self.show_box = gui.add_checkbox("bounding box", initial_value=True)
            self.show_axes = gui.add_checkbox("axes", initial_value=True)
            self.clicked = gui.add_markdown("click a point to see its coordinates and fields")
        self.colour_by.on_update(lambda _: self._recolour())
        self.point_size.on_update(lambda _: self._resize())
        self.show_box.on_update(lambda _: self._toggle("box", self.show_box.value))
        self.show_axes.on_update(lambda _: self._toggle("axes", self.show_axes.value))
        self.nodes: dict[str, Any] = {}
        viewer.server.scene.on_click()(self._picked)

    # -- loading ----------------------------------------------------------------------------------

    def load(self) -> None:
        """Read the file and show it; a large LAZ file is previewed first.

        Files over :data:`WORKER_ABOVE_BYTES` are read in a worker process, at a lower
        priority: lazrs holds Python's global lock for the whole decompression (3.5 s for 10
        million points), which would stall the server thread sending the page to the browser,
        and the browser needs the processor to draw the preview meanwhile.
        """
        if self.path.stat().st_size <= WORKER_ABOVE_BYTES:
            prepared = read_prepared(self.path, self.max_points)
        else:
            preview = laz_preview(self.path, max(1, self.max_points // PREVIEW_FRACTION))
            if preview is not None:
                cloud, total = preview
                self.show(prepare(cloud, self.max_points, total=total, preview=True))
            context = multiprocessing.get_context("fork")
            with ProcessPoolExecutor(1, mp_context=context, initializer=start_worker, initargs=(os.getpid(),)) as worker:
                prepared = worker.submit(read_prepared, self.path, self.max_points).result()
        if isinstance(prepared, str):
            raise PointfieldError(prepared)
        self.show(prepared)

    def show(self, prepared: Prepared) -> None:
        """Put ``prepared`` on the page in place of what was there (the preview, at first)."""
        low, high = prepared.low, prepared.high
        origin = self.viewer.recentre(low, high)
        self.viewer.grow(low, high)
        display = (prepared.points - origin).astype(np.float32)
        with self.lock:
            first = self.shown is None
            # The preview's points are sparser: the point size follows the cloud that replaces it.
            sized_for_preview = not first and self.shown.preview
            self.shown, self.display = prepared, display
            modes = colour_modes(prepared.fields)
            self.colour_by.options = modes
            if first or self.colour_by.value not in modes:  # the file's own colours, where it has them
                self.colour_by.value = "rgb" if "rgb" in modes else "height"
            if first or sized_for_preview:
                spacing = typical_spacing(low, high, len(display))
                self.point_size.min = round_down(spacing / 10)
                self.point_size.max = round_down(spacing * 20)
                self.point_size.step = self.point_size.min
                self.point_size.value = round_down(spacing)
            self._draw()
            if first:  # after the points, so that the first picture of the page has them
                self._frame(low, high, origin)
            self.status.content = self._describe()
        if first:
            self._first_look(prepared)

    def _first_look(self, prepared: Prepared) -> None:
        """Start the page's camera where the sensor stood, upright as it saw the scene, when the file
        says where that was; else obliquely from above, z up."""
        if prepared.sensor is not None:
            sensor = prepared.sensor
            self.viewer.first_look(sensor.target, sensor.eye, up=tuple(sensor.up))
            return
        low, high = prepared.low, prepared.high
        centre = (low + high) / 2
        size = float(np.linalg.norm(high - low)) or 1.0
        self.viewer.first_look(centre, centre + size * np.array([0.3, -0.5, 0.4]), up=tuple(UP))

    def _describe(self) -> str:
        shown = self.shown
        kind = "faces" if shown.faces is not None else "points"
        if shown.preview:
            head = f"**preview**: showing {shown.count:,} of {shown.total:,} {kind} while the file is read"
        elif shown.count < shown.total:
            head = f"showing {shown.count:,} of {shown.total:,} {kind}"
        else:
            head = f"showing all {shown.total:,} {kind}"
        bounds = "  \n".join(f"{axis} {lo:,.2f} .. {hi:,.2f}" for axis, lo, hi in zip("xyz", shown.low, shown.high))
        return f"{head}  \n{self.path.name} ({shown.format})  \n{bounds}"

    # -- drawing ----------------------------------------------------------------------------------

    def _draw(self) -> None:
        shown, display = self.shown, self.display
        colours = colours_for(self.colour_by.value, display, shown.fields)
        scene = self.viewer.server.scene
        if shown.faces is not None:
            # trimesh (scipy, networkx) takes 0.7 s to import: a page of clouds never waits for it.
            import trimesh

            self.viewer.light_surfaces()
            mesh = trimesh.Trimesh(display, shown.faces, vertex_colors=colours, process=False)
            self.node = scene.add_mesh_trimesh(f"/{self.name}/mesh", mesh)
        else:
            self.node = scene.add_point_cloud(
                f"/{self.name}/points", display, colours, point_size=float(self.point_size.value),
                precision="float32", point_shape="square", point_shading="flat",
            )

    def _recolour(self) -> None:
        with self.lock:
            if self.node is None or self.colour_by.value not in colour_modes(self.shown.fields):
                return
            if self.shown.faces is not None:
                self._draw()
            else:
                self.node.colors = colours_for(self.colour_by.value, self.display, self.shown.fields)

    def _resize(self) -> None:
        with self.lock:
            if self.node is not None and self.shown.faces is None:
                self.node.point_size = float(self.point_size.value)

    def _frame(self, low: np.ndarray, high: np.ndarray, origin: np.ndarray) -> None:
        scene = self.viewer.server.scene
        size = np.maximum(high - low, 1e-6)
        self.nodes["box"] = scene.add_box(f"/{self.name}/box", color=(255, 140, 0), dimensions=tuple(size),
                                          wireframe=True, position=tuple((low + high) / 2 - origin),
                                          visible=self.show_box.value)
        length = float(np.linalg.norm(size)) / 10
        self.nodes["axes"] = scene.add_frame(f"/{self.name}/axes", axes_length=length, axes_radius=length / 40,
                                             position=tuple(low - origin), visible=self.show_axes.value)

    def _toggle(self, name: str, visible: bool) -> None:
        if name in self.nodes:
            self.nodes[name].visible = visible

    def _picked(self, event: Any) -> None:
        """Report the shown point nearest the clicked ray, in real coordinates, with its fields."""
        with self.lock:
            shown, display = self.shown, self.display
        if shown is None or shown.faces is not None:
            return
        index = nearest_to_ray(display, np.asarray(event.ray_origin), np.asarray(event.ray_direction))
        if index is None:
            return
        x, y, z = shown.points[index]
        values = ", ".join(f"{name} {format_value(values[index])}" for name, values in shown.fields.items())
        self.clicked.content = f"**clicked** x {x:,.3f}, y {y:,.3f}, z {z:,.3f}  \n{values}"


def nearest_to_ray(points: np.ndarray, origin: np.ndarray, direction: np.ndarray,
                   angle: float = 0.01) -> int | None:
    """Index of the point a click's ray hits: of the points within ``angle`` (radians) of the ray,
    the one nearest the camera; None when no point is that close (a click on empty space)."""
    direction = direction / np.linalg.norm(direction)
    relative = points.astype(np.float64) - origin
    along = relative @ direction
    across = np.linalg.norm(relative - along[:, None] * direction, axis=1)
    near = np.flatnonzero((along > 0) & (across <= angle * along))
    if len(near) == 0:
        return None
    return int(near[np.argmin(along[near])])


def format_value(value: Any) -> str:
    array = np.asarray(value)
    if array.ndim:
        return "(" + ", ".join(format_value(v) for v in array) + ")"
    return f"{array.item():.4g}" if array.dtype.kind == "f" else str(array.item())


def typical_spacing(low: np.ndarray, high: np.ndarray, count: int) -> float:
    """A point size that leaves few gaps: the spacing of ``count`` points spread over the box's two largest sides."""
    sides = np.sort(np.maximum(np.asarray(high) - np.asarray(low), 0))[::-1]
    area = sides[0] * sides[1] if sides[1] > 0 else sides[0] ** 2
    return float(math.sqrt(area / max(count, 1))) or 1e-3


def round_down(value: float) -> float:
    """``value`` rounded down to one significant digit (a slider's step), never zero."""
    if value <= 0:
        return 1e-6
    power = 10 ** math.floor(math.log10(value))
    return float(math.floor(value / power) * power)


def mesh_for_display(mesh: Mesh, max_faces: int) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """A mesh's vertices, triangles and vertex fields, quadric-decimated to ``max_faces`` when larger."""
    vertices = np.asarray(mesh.points, np.float64)
    triangles = mesh.triangles()
    fields = {name: np.asarray(values) for name, values in mesh.fields.items()}
    if len(triangles) > max_faces:
        vertices, triangles = fast_simplification.simplify(
            vertices.astype(np.float32), triangles.astype(np.int32), target_reduction=1 - max_faces / len(triangles)
        )
        fields = {}  # decimation moves vertices: their fields no longer apply
    return vertices, triangles, fields


def show_cloud(viewer: Viewer, path: str | os.PathLike[str], name: str | None = None,
               max_points: int = DEFAULT_MAX_POINTS) -> CloudView:
    """Add a cloud or mesh file to ``viewer``'s page (see the module doc); returns its view."""
    path = Path(path)
    view = CloudView(viewer, path, name or path.stem, max_points)
    view.load()
    return view
