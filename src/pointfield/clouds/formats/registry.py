"""The one registry of point-cloud file formats behind :func:`read` and :func:`write`.

A format is found by, in order: the ``format=`` argument, the file's signature (its first bytes:
``ply``, ``# .PCD``, ``LASF``, ...), then its suffix. The signature wins over the suffix so that a
``.pcd`` file that really holds PLY still reads.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pointfield.atomic import atomic_path
from pointfield.clouds.cloud import PointCloud, Records
from pointfield.errors import FormatError

SIGNATURE_BYTES = 64


@dataclass(frozen=True)
class Format:
    """One file format: how to recognise, read and write it.

    ``read(path, **options)`` returns a PointCloud (a Mesh when the file has faces, Records when
    it has no coordinates). ``write(path, cloud, encoding, **options)`` writes to ``path``, which
    the registry makes a temporary file that is renamed into place only when writing succeeds.
    ``encodings`` lists the encodings ``write`` accepts, the default first, and
    ``suffix_encodings`` the default for suffixes that imply another (``.laz`` -> ``laz``);
    ``aliases`` maps the generic names the command line uses (``ascii``, ``binary``,
    ``compressed``) onto them. ``holds_faces`` says whether the format stores a Mesh's faces,
    ``needs_faces`` whether it stores only meshes (OBJ, STL, glTF: a cloud without faces is
    refused), ``holds_records`` whether it stores :class:`Records` (fields without x, y, z).

    A format that streams (:mod:`pointfield.clouds.formats.chunked`) also gives
    ``open_chunks(path, **options)``, a :class:`~pointfield.clouds.formats.chunked.ChunkSource` for
    the file or None when this file must be read whole, the names of the ``chunk_options`` it
    takes (``columns`` for ``.bin``; ``bounds``, ``level``, ``resolution`` for COPC), and
    ``chunk_writer(encoding)``, the :class:`~pointfield.clouds.formats.chunked.ChunkWriter` class
    for an encoding or None when that encoding is written whole. ``check_output(path)`` raises a
    FormatError for an output name the format refuses (LAS: ``.copc.laz``), before anything is
    written.
    """

    name: str
    description: str
    suffixes: tuple[str, ...]
    read: Callable[..., Any]
    write: Callable[..., None] | None = None
    encodings: tuple[str, ...] = ()
    aliases: Mapping[str, str] = field(default_factory=dict)
    signature: Callable[[bytes], bool] | None = None
    suffix_encodings: Mapping[str, str] = field(default_factory=dict)
    holds_faces: bool = False
    needs_faces: bool = False
    holds_records: bool = False
    open_chunks: Callable[..., Any] | None = None
    chunk_options: tuple[str, ...] = ()
    chunk_writer: Callable[[str | None], type | None] | None = None
    check_output: Callable[[Path], None] | None = None

    def resolve_encoding(self, encoding: str | None, path: Path) -> str | None:
        if encoding is None:
            default = self.encodings[0] if self.encodings else None
            return self.suffix_encodings.get(path.suffix.lower(), default)
        resolved = self.aliases.get(encoding, encoding)
        if resolved not in self.encodings:
            offered = sorted(set(self.encodings) | set(self.aliases))
            raise FormatError(
                path, f"{self.name} has no encoding {encoding!r}; expected one of {offered}"
            )
        return resolved


_FORMATS: list[Format] = []


def register(fmt: Format) -> Format:
    """Add a format to the registry (each format module registers itself on import)."""
    _FORMATS.append(fmt)
    return fmt


def formats() -> list[Format]:
    return list(_FORMATS)


def format_named(name: str) -> Format:
    for fmt in _FORMATS:
        if fmt.name == name.lower():
            return fmt
    raise ValueError(f"unknown format {name!r}; expected one of {[f.name for f in _FORMATS]}")


def format_of(path: str | os.PathLike[str], *, for_writing: bool = False) -> Format:
    """The format of ``path``: its signature when it exists and is being read, else its suffix."""
    path = Path(path)
    if not for_writing:
        with open(path, "rb") as file:
            head = file.read(SIGNATURE_BYTES)
        for fmt in _FORMATS:
            if fmt.signature is not None and fmt.signature(head):
                return fmt
    suffix = path.suffix.lower()
    for fmt in _FORMATS:
        if suffix in fmt.suffixes:
            return fmt
    known = sorted(s for f in _FORMATS for s in f.suffixes)
    raise FormatError(path, f"unknown point-cloud format (suffix {suffix!r}); expected one of {known}")


def read(path: str | os.PathLike[str], format: str | None = None, **options: Any) -> Any:
    """Read a point cloud, mesh or record file in any registered format.

    Returns a :class:`PointCloud`, a :class:`Mesh` when the file has faces, or :class:`Records`
    for files without x/y/z. ``metadata["format"]`` and ``metadata["encoding"]`` say what the
    file was. Options go to the format's reader (e.g. ``columns=5`` for a nuScenes ``.bin``).

    Raises FileNotFoundError for a missing file and FormatError for one that cannot be read.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    fmt = format_named(format) if format else format_of(path)
    cloud = fmt.read(path, **options)
    cloud.metadata["format"] = fmt.name
    return cloud


def write(
    path: str | os.PathLike[str],
    cloud: PointCloud,
    format: str | None = None,
    encoding: str | None = None,
    **options: Any,
) -> None:
    """Write ``cloud`` atomically; the format comes from ``format=`` or the suffix of ``path``.

    ``encoding`` is the format's own name (``binary_big_endian``, ``binary_compressed``) or a
    generic one (``ascii``, ``binary``, ``compressed``); None picks the format's default.
    """
    path = Path(path)
    fmt = format_named(format) if format else format_of(path, for_writing=True)
    if fmt.write is None:
        raise FormatError(path, f"pointfield reads {fmt.name} but cannot write it")
    resolved = fmt.resolve_encoding(encoding, path)
    if fmt.check_output is not None:
        fmt.check_output(path)
    if isinstance(cloud, Records) and not fmt.holds_records:
        raise FormatError(
            path,
            f"{path.suffix or fmt.name} needs points; write records without x/y/z as .npy, .pcd "
            f"or .ply",
        )
    faces = getattr(cloud, "faces", ())
    if fmt.needs_faces and not len(faces):
        raise FormatError(path, f"{path.suffix or fmt.name} holds meshes; a cloud without faces cannot be "
                                "written as one (write .ply or .off)")
    if len(faces) and not fmt.holds_faces:
        warnings.warn(
            f"{path}: {fmt.name} holds no faces; {len(faces)} faces were not written", stacklevel=2
        )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with atomic_path(path) as tmp:
                fmt.write(tmp, cloud, encoding=resolved, **options)
        except FormatError as error:
            raise FormatError(path, error.reason) from None
    for warning in caught:  # about the user's file, not the temporary one it was written as
        warnings.warn_explicit(_naming(path, tmp, str(warning.message)), warning.category, *_caller())


def _naming(path: Path, tmp: Path, message: str) -> str:
    """``message`` with the temporary file's name replaced by ``path``'s, and ``path`` first."""
    message = message.replace(str(tmp), str(path)).replace(tmp.name, path.name)
    return message if str(path) in message else f"{path}: {message}"


def _caller() -> tuple[str, int]:
    """The file and line of the first frame outside pointfield: where a user's code called it."""
    import sys

    package = str(Path(__file__).resolve().parents[2])
    frame = sys._getframe(1)
    while frame.f_back is not None and str(Path(frame.f_code.co_filename).resolve()).startswith(package):
        frame = frame.f_back
    return frame.f_code.co_filename, frame.f_lineno
