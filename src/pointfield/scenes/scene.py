"""Scene: posed images -- cameras, lazily loaded images, named splits, sparse points, bounds.

A scene is what every reconstruction method starts from. Cameras follow pointfield's one
convention (OpenCV, camera-to-world; see :mod:`pointfield.scenes.cameras`), whatever format the
scene was read from.

Images
    Loaded on demand (``scene.image(i)``) as float32 ``(H, W, 3)`` in [0, 1]. Images with an
    alpha channel are composited onto ``scene.background``: ``rgb * a + background * (1 - a)``.
    8-bit files are divided by 255, 16-bit by 65535; grey images are repeated to RGB.
Downscaling
    ``scene.downscaled(f)`` (integer f) averages f x f blocks ("area" resampling; alpha is
    averaged with premultiplied colour so compositing after downscaling equals downscaling after
    compositing) and scales the cameras to match (:meth:`Cameras.scaled`).
Splits
    ``scene.splits`` maps a name ("train", "val", "test") to frame indices. ``with_holdout(n)``
    holds every n-th training frame (0, n, 2n, ... as LLFF does) out as "test" for datasets
    without one.
Depth and masks
    Optional per frame: ``scene.depth(i)`` float32 ``(H, W)`` z-depth in world units, 0 where
    there is no surface; ``scene.mask(i)`` bool ``(H, W)``, True on the objects.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.formats.npy import read_array
from pointfield.errors import FormatError, PointfieldError
from pointfield.scenes.cameras import Cameras

BACKGROUNDS = {"white": (1.0, 1.0, 1.0), "black": (0.0, 0.0, 0.0)}


class SceneError(PointfieldError):
    """A scene cannot do what was asked: a frame without an image, an unknown split, ..."""


@dataclass(frozen=True)
class Frame:
    """One posed view's data sources; its camera is the matching entry of ``Scene.cameras``.

    ``name`` is the dataset's name for the view (Blender ``file_path``, COLMAP image name). The
    image comes from ``image_path`` or, for in-memory scenes (npz, synthetic), ``image``
    (``(H, W, C)``, C in 1..4, uint8/uint16/float). Depth and mask likewise, optional.
    ``depth_scale`` converts stored depth values to world units.
    """

    name: str
    image_path: Path | None = None
    image: np.ndarray | None = field(default=None, repr=False)
    depth_path: Path | None = None
    depth: np.ndarray | None = field(default=None, repr=False)
    depth_scale: float = 1.0
    mask_path: Path | None = None
    mask: np.ndarray | None = field(default=None, repr=False)

    @property
    def has_image(self) -> bool:
        return self.image_path is not None or self.image is not None

    @property
    def has_depth(self) -> bool:
        return self.depth_path is not None or self.depth is not None

    @property
    def has_mask(self) -> bool:
        return self.mask_path is not None or self.mask is not None


@dataclass(eq=False)
class Scene:
    """Posed images in pointfield's camera convention.

    - ``cameras``: :class:`Cameras`, one per frame, already scaled for ``downscale``.
    - ``frames``: one :class:`Frame` per camera.
    - ``splits``: name -> int64 frame indices.
    - ``points``: optional sparse points (COLMAP ``points3D``) with ``colors`` uint8 (P, 3).
    - ``near_far``: optional ``(N, 2)`` per-frame near and far distances along the optical axis.
    - ``aabb``: optional ``(2, 3)`` min / max corners of the region of interest, world units.
    - ``background``: ``(3,)`` float32 colour alpha is composited onto.
    - ``downscale``: integer factor images are downscaled by when loaded.
    - ``metadata``: ``format``, ``path``, ``frames_listed`` and what else the format says.
    """

    cameras: Cameras
    frames: list[Frame]
    splits: dict[str, np.ndarray] = field(default_factory=dict)
    points: PointCloud | None = None
    near_far: np.ndarray | None = None
    aabb: np.ndarray | None = None
    background: np.ndarray = field(default_factory=lambda: np.ones(3, np.float32))
    downscale: int = 1
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.cameras) != len(self.frames):
            raise ValueError(f"{len(self.cameras)} cameras for {len(self.frames)} frames")
        if not self.splits:
            self.splits = {"train": np.arange(len(self.frames))}
        self.splits = {name: np.asarray(index, dtype=np.int64) for name, index in self.splits.items()}
        self.background = parse_background(self.background)

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        splits = ", ".join(f"{name} {len(index)}" for name, index in self.splits.items())
        points = f", {len(self.points)} points" if self.points is not None else ""
        return f"Scene({self.metadata.get('format', 'scene')}, {len(self)} frames ({splits}), {self.cameras!r}{points})"

    # -- views of the scene ------------------------------------------------------------------

    def split(self, name: str) -> Scene:
        """The scene of split ``name``'s frames; it has one split, ``name``, holding all of them."""
        if name not in self.splits:
            raise SceneError(f"scene has no {name!r} split (it has {', '.join(self.splits) or 'none'})")
        subset = self.subset(self.splits[name])
        subset.splits = {name: np.arange(len(subset))}
        return subset

    def subset(self, indices) -> Scene:
        """The scene of frames ``indices`` (in that order); splits keep the frames they contain."""
        indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        new_position = np.full(len(self), -1, dtype=np.int64)
        new_position[indices] = np.arange(len(indices))
        splits = {}
        for name, members in self.splits.items():
            kept = new_position[members]
            splits[name] = np.sort(kept[kept >= 0])
        return replace(
            self,
            cameras=self.cameras[indices],
            frames=[self.frames[i] for i in indices],
            splits=splits,
            near_far=None if self.near_far is None else self.near_far[indices],
            metadata=dict(self.metadata),
        )

    def with_holdout(self, every: int) -> Scene:
        """Hold every ``every``-th training frame (0, every, 2 every, ...) out as "test".

        For datasets without test images, as LLFF's ``llffhold`` does; other splits ("val") stay.
        A scene that already has a test split with images is returned unchanged, with a warning.
        """
        if int(every) != every or every < 2:
            raise SceneError(f"--holdout-every must be an integer >= 2, got {every}")
        existing = self.splits.get("test")
        if existing is not None and len(existing) and any(self.frames[i].has_image for i in existing):
            warnings.warn("scene already has a test split; holdout ignored", stacklevel=2)
            return self
        candidates = self.splits.get("train", np.arange(len(self)))
        held_out = np.arange(len(candidates)) % int(every) == 0
        splits = {name: index for name, index in self.splits.items() if name not in ("train", "test")}
        splits = {"train": candidates[~held_out], **splits, "test": candidates[held_out]}
        return replace(self, splits=splits, metadata={**self.metadata, "holdout_every": int(every)})

    def downscaled(self, factor: int) -> Scene:
        """The scene with images downscaled by integer ``factor`` on load, cameras scaled to match."""
        if factor == 1:
            return self
        return replace(self, cameras=self.cameras.scaled(factor), downscale=self.downscale * int(factor))

    def with_background(self, background) -> Scene:
        """The scene compositing alpha onto ``background`` ("white", "black" or an RGB triple in [0, 1])."""
        return replace(self, background=parse_background(background))

    # -- pixels -------------------------------------------------------------------------------

    def rgba(self, index: int) -> np.ndarray:
        """Frame ``index``'s image as stored (alpha not composited), downscaled: float32 ``(H, W, 3|4)``."""
        frame = self.frames[index]
        pixels = _as_float_color(
            self._read_pixels(index, frame.image_path, frame.image, "image"), frame, self
        )
        pixels = _area_downscale_rgba(pixels, self.downscale)
        self._check_size(index, pixels, "image", frame.image_path)
        return pixels

    def pixels(self, index: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Frame ``index``'s :meth:`image` and :meth:`alpha` from one decode of its file.

        Training needs both of every frame; asking for each alone decodes the file twice (half of
        a short run's start-up on lego at ``--downscale 8``).
        """
        pixels = self.rgba(index)
        if pixels.shape[2] == 3:
            return pixels, None
        alpha = pixels[..., 3:]
        return pixels[..., :3] * alpha + self.background * (1 - alpha), pixels[..., 3]

    def image(self, index: int) -> np.ndarray:
        """Frame ``index``'s image, float32 ``(H, W, 3)`` in [0, 1], alpha composited on the background."""
        return self.pixels(index)[0]

    def alpha(self, index: int) -> np.ndarray | None:
        """Frame ``index``'s alpha channel, float32 ``(H, W)``, or None when the image has none."""
        return self.pixels(index)[1]

    def images(self, indices=None) -> np.ndarray:
        """Images of frames ``indices`` (default all), stacked ``(K, H, W, 3)``; sizes must agree."""
        indices = range(len(self)) if indices is None else indices
        loaded = [self.image(int(i)) for i in indices]
        if len({image.shape for image in loaded}) > 1:
            raise SceneError("frames have different image sizes; load them one at a time with image(i)")
        return np.stack(loaded) if loaded else np.zeros((0, 0, 0, 3), np.float32)

    def depth(self, index: int) -> np.ndarray | None:
        """Frame ``index``'s z-depth map, float32 ``(H, W)`` in world units (0 = no surface), or None."""
        frame = self.frames[index]
        if not frame.has_depth:
            return None
        stored = self._read_pixels(index, frame.depth_path, frame.depth, "depth")
        if stored.ndim == 3:
            stored = stored[..., 0]
        depth = stored.astype(np.float32) * np.float32(frame.depth_scale)
        depth = _block_mean_of_valid(depth, depth > 0, self.downscale)
        self._check_size(index, depth, "depth", frame.depth_path)
        return depth

    def mask(self, index: int) -> np.ndarray | None:
        """Frame ``index``'s object mask, bool ``(H, W)`` (True on objects), or None."""
        frame = self.frames[index]
        if not frame.has_mask:
            return None
        stored = self._read_pixels(index, frame.mask_path, frame.mask, "mask")
        if stored.ndim == 3:
            stored = stored[..., 0]
        covered = (stored > 0).astype(np.float32)
        mask = _block_mean(covered, self.downscale) >= 0.5
        self._check_size(index, mask, "mask", frame.mask_path)
        return mask

    def _read_pixels(self, index: int, path: Path | None, array: np.ndarray | None, what: str) -> np.ndarray:
        if array is not None:
            return array
        if path is None:
            raise SceneError(f"frame {index} ({self.frames[index].name}) has no {what}")
        where = f"frame {index} ({self.frames[index].name})"
        if path.suffix.lower() == ".npy":
            return load_npy(path, f"{where}: {what}")
        return read_image_file(path, where)

    def _check_size(self, index: int, pixels: np.ndarray, what: str, source: Path | None) -> None:
        expected = (int(self.cameras.height[index]), int(self.cameras.width[index]))
        if pixels.shape[:2] != expected:
            source = source or self.metadata.get("path", "scene")
            found = f"{pixels.shape[1]}x{pixels.shape[0]}" if pixels.ndim >= 2 else f"of shape {pixels.shape}"
            raise FormatError(
                source,
                f"frame {index} ({self.frames[index].name}): {what} is {found} "
                f"but its camera is {expected[1]}x{expected[0]}",
            )


def parse_background(background) -> np.ndarray:
    """``"white"``, ``"black"`` or an RGB triple in [0, 1] -> float32 ``(3,)``."""
    if isinstance(background, str):
        if background not in BACKGROUNDS:
            raise SceneError(
                f"background must be {', '.join(BACKGROUNDS)} or three numbers, got {background!r}"
            )
        background = BACKGROUNDS[background]
    color = np.asarray(background, dtype=np.float32).reshape(-1)
    if color.shape != (3,) or not np.all((color >= 0) & (color <= 1)):
        raise SceneError(f"background must be an RGB triple in [0, 1], got {background!r}")
    return color


def read_image_file(path: Path, where: str) -> np.ndarray:
    """Decode an image file with imageio; any failure becomes a FormatError naming file and frame."""
    import imageio.v3 as iio

    try:
        return np.asarray(iio.imread(path))
    except FileNotFoundError:
        raise FormatError(path, f"{where}: image file not found") from None
    except Exception as error:  # noqa: BLE001 - re-raised as FormatError; decoders raise anything from OSError to SyntaxError on bad bytes
        raise FormatError(path, f"{where}: cannot decode image ({type(error).__name__}: {error})") from None


def _as_float_color(pixels: np.ndarray, frame: Frame, scene: Scene) -> np.ndarray:
    """Stored pixels -> float32 ``(H, W, 3|4)`` in [0, 1] (grey repeated to RGB)."""
    where = frame.image_path or scene.metadata.get("path", "scene")
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.ndim != 3 or pixels.shape[2] not in (1, 2, 3, 4):
        raise FormatError(where, f"frame {frame.name}: image has shape {pixels.shape}, expected (H, W, 1..4)")
    if pixels.dtype == np.uint8:
        values = pixels.astype(np.float32) / 255
    elif pixels.dtype == np.uint16:
        values = pixels.astype(np.float32) / 65535
    elif pixels.dtype == np.bool_ or np.issubdtype(pixels.dtype, np.floating):
        values = pixels.astype(np.float32)
    else:
        raise FormatError(where, f"frame {frame.name}: image has unsupported pixel type {pixels.dtype}")
    if values.shape[2] in (1, 2):
        values = np.concatenate([np.repeat(values[..., :1], 3, axis=2), values[..., 1:]], axis=2)
    return values


def _block_mean(values: np.ndarray, factor: int) -> np.ndarray:
    """Mean over ``factor x factor`` blocks of ``(H, W, ...)``; a partial edge block is dropped."""
    if factor == 1:
        return values
    height, width = values.shape[0] // factor, values.shape[1] // factor
    cropped = values[: height * factor, : width * factor]
    blocks = cropped.reshape(height, factor, width, factor, *values.shape[2:])
    return blocks.mean(axis=(1, 3), dtype=np.float32)


def _area_downscale_rgba(pixels: np.ndarray, factor: int) -> np.ndarray:
    """Area downscaling; RGBA averages premultiplied colour so compositing commutes with it."""
    if factor == 1:
        return pixels
    if pixels.shape[2] == 3:
        return _block_mean(pixels, factor)
    alpha = pixels[..., 3:]
    premultiplied = _block_mean(np.concatenate([pixels[..., :3] * alpha, alpha], axis=2), factor)
    mean_alpha = premultiplied[..., 3:]
    color = np.divide(
        premultiplied[..., :3], mean_alpha, out=np.zeros_like(premultiplied[..., :3]), where=mean_alpha > 0
    )
    return np.concatenate([color, mean_alpha], axis=2)


def _block_mean_of_valid(values: np.ndarray, valid: np.ndarray, factor: int) -> np.ndarray:
    """Block mean of the valid values only (0 where a block has none): depth must not average in holes."""
    if factor == 1:
        return np.where(valid, values, 0).astype(np.float32)
    total = _block_mean(np.where(valid, values, 0).astype(np.float32), factor)
    count = _block_mean(valid.astype(np.float32), factor)
    return np.divide(total, count, out=np.zeros_like(total), where=count > 0)


def load_npy(path: Path, where: str = "array") -> np.ndarray:
    """A numeric ``.npy`` array (depth maps, LLFF poses), read by the cloud reader's size-checked path.

    The declared shape is checked against the bytes present before anything is allocated
    (:func:`pointfield.clouds.formats.npy.read_array`); arrays of anything but numbers are refused.
    """
    if not path.is_file():
        raise FormatError(path, "file not found")
    array = read_array(path)
    if array.dtype.kind not in "biuf":
        raise FormatError(path, f"{where}: array has dtype {array.dtype}; expected numbers")
    return np.array(array)  # a copy: the array may view a memory map of the file
