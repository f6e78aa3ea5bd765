"""What a format offers to read and write a window of points at a time, for :mod:`pointfield.streaming`.

A format that can stream registers two things beside its whole-file reader and writer
(:class:`~pointfield.clouds.formats.registry.Format`): ``open_chunks(path, **options)``, which
returns a :class:`ChunkSource` for the file (or None when this file must be read whole: an ascii
PLY, a mesh), and ``chunk_writer(encoding)``, the :class:`ChunkWriter` subclass that writes that
encoding (or None when it is written whole). Each format's chunk rules live in its own package;
streaming only asks the registry, so adding a streaming format touches that format's package only.

Reading: ``source.read(start, stop)`` is the cloud of points ``start .. stop - 1``, with every
field and the metadata :func:`pointfield.read` gives, and ``source.chunks(points)`` walks the
file in windows of ``points``. Concatenated, the windows are exactly what :func:`pointfield.read`
returns. :class:`RecordSource` serves every format of fixed-size records (PLY and PCD binary,
``.bin``, NPY) with ``pread``: nothing is mapped, so resident memory is the window's.

Writing: a :class:`ChunkWriter` writes into a temporary file beside ``path`` that is renamed onto
it when :meth:`ChunkWriter.close` succeeds; on an exception the temporary file is removed and
``path`` is left as it was. The bytes are those :func:`pointfield.write` writes for the
concatenated chunks. :class:`BodyFirstWriter` serves formats whose header states the point count.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO, Self

import numpy as np

from pointfield.atomic import atomic_path
from pointfield.clouds.cloud import PointCloud, Records
from pointfield.clouds.formats.registry import format_of
from pointfield.errors import FormatError, PointfieldError

DEFAULT_CHUNK_POINTS = 1 << 20

Bounds = tuple[np.ndarray, np.ndarray]


def concatenate(clouds: list[PointCloud], metadata: dict[str, Any] | None = None) -> PointCloud:
    """One cloud of the points and fields of ``clouds``, in order (metadata of the first)."""
    if not clouds:
        raise ValueError("nothing to concatenate")
    first = clouds[0]
    return PointCloud(
        np.concatenate([c.points for c in clouds]),
        {name: np.concatenate([c.fields[name] for c in clouds]) for name in first.fields},
        None,
        dict(first.metadata if metadata is None else metadata),
    )


class ChunkSource:
    """One file opened for windows of points (see the module docstring).

    ``count`` is the number of points stored (NaN points included), ``metadata`` what
    :func:`pointfield.read` puts in ``cloud.metadata``, ``streams`` False for files read whole,
    and ``aligned`` the window size a reader seeks to cheaply (a LAZ chunk), 1 otherwise.
    """

    path: Path
    count: int
    metadata: dict[str, Any]
    streams = True
    aligned = 1

    def read(self, start: int, stop: int) -> PointCloud:
        """The cloud of points ``start .. stop - 1``."""
        raise NotImplementedError

    def chunks(
        self, points: int = DEFAULT_CHUNK_POINTS, start: int = 0, stop: int | None = None
    ) -> Iterator[PointCloud]:
        """Windows of ``points`` points from ``start`` up to ``stop`` (default: the end)."""
        stop = self.count if stop is None else min(stop, self.count)
        for low in range(start, stop, points):
            yield self.read(low, min(low + points, stop))

    def bounds_hint(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(min, max)`` of the points as the file's header states them, or None.

        A hint, not a fact: headers can be stale. Callers that need exact bounds check it.
        """
        return None

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r}, {self.count} points)"


class RecordSource(ChunkSource):
    """``count`` records of ``dtype`` at byte ``offset``, read with ``pread`` and turned into
    clouds by ``convert`` (the format's own records-to-cloud code).

    A file too short for its ``count`` records is refused here, before anything is written from
    it: the error names the file and the ``what`` (point, vertex, record) where its data ends.
    """

    def __init__(
        self,
        path: Path,
        dtype: np.dtype,
        offset: int,
        count: int,
        convert: Callable[[np.ndarray], PointCloud | Records],
        format_name: str,
        what: str = "point",
    ):
        self.path, self.dtype, self.offset, self.count = path, dtype, offset, count
        self.convert, self.format_name = convert, format_name
        size = path.stat().st_size
        if dtype.itemsize == 0 and count:  # a header declaring records of no values (a hostile file)
            raise FormatError(path, f"its header declares {count:,} {what} records that hold no values")
        whole = (size - offset) // dtype.itemsize if size > offset else 0
        if whole < count:
            inside = size - offset - whole * dtype.itemsize
            where = (
                f"{what} {whole:,} of {count:,} is cut short {inside} bytes into its "
                f"{dtype.itemsize}-byte record"
                if inside
                else f"only {whole:,} of its {count:,} {what}s are present"
            )
            raise FormatError(path, f"the file ends at byte {size:,}: {where}")
        self.metadata = dict(self._convert(np.zeros(0, dtype)).metadata)

    def read(self, start: int, stop: int) -> PointCloud:
        size = self.dtype.itemsize
        with open(self.path, "rb") as file:
            data = os.pread(file.fileno(), (stop - start) * size, self.offset + start * size)
        return self._convert(np.frombuffer(data, self.dtype))

    def chunks(
        self, points: int = DEFAULT_CHUNK_POINTS, start: int = 0, stop: int | None = None
    ) -> Iterator[PointCloud]:
        stop = self.count if stop is None else min(stop, self.count)
        size = self.dtype.itemsize
        with open(self.path, "rb") as file:
            for low in range(start, stop, points):
                high = min(low + points, stop)
                data = os.pread(file.fileno(), (high - low) * size, self.offset + low * size)
                yield self._convert(np.frombuffer(data, self.dtype))

    def _convert(self, records: np.ndarray) -> PointCloud:
        cloud = self.convert(records)
        if not isinstance(cloud, PointCloud):
            raise PointfieldError(f"{self.path}: its records have no x, y, z; there is nothing to stream")
        cloud.metadata["format"] = self.format_name
        return cloud


class ChunkWriter:
    """Writes chunks into a temporary file renamed onto ``path`` at :meth:`close`.

    Subclasses write the first chunk's layout in :meth:`_begin`, each chunk in :meth:`_write`
    and whatever follows the points in :meth:`_finish`. ``count`` is the points written so far.
    ``bounds`` ``(min, max)`` of the finite points to come; a writer whose header needs them
    before the first point (LAS) says so with ``needs_bounds``, and streaming then parks the
    chunks until it knows them. ``into`` is a file to write instead of a temporary file of the
    writer's own, for a caller that owns the temporary file and its renaming.
    """

    streams = True
    needs_bounds = False

    def __init__(
        self,
        path: str | os.PathLike[str],
        encoding: str | None = None,
        bounds: Bounds | None = None,
        *,
        into: Path | None = None,
    ):
        self.path = Path(path)
        self.format = format_of(self.path, for_writing=True)
        self.encoding = self.format.resolve_encoding(encoding, self.path)
        if self.format.check_output is not None:
            self.format.check_output(self.path)
        if self.needs_bounds and bounds is None:
            raise ValueError(f"{self.path}: a {type(self).__name__} needs the bounds of the points to come")
        self.bounds = bounds
        self.count = 0
        self.template: PointCloud | None = None
        self._notes: dict[str, type[Warning]] = {}
        self._stack = contextlib.ExitStack()
        self.tmp = into if into is not None else self._stack.enter_context(atomic_path(self.path))
        self._closed = False

    def write(self, cloud: PointCloud) -> None:
        """Append the points of ``cloud`` (same fields as the first chunk)."""
        if self._closed:
            raise ValueError(f"{self.path}: the writer is closed")
        with self._collect_warnings():
            if self.template is None:
                self.template = cloud
                self._begin(cloud)
            elif cloud.fields.keys() != self.template.fields.keys():
                raise FormatError(
                    self.path,
                    f"a chunk has fields {sorted(cloud.fields)}; the first had "
                    f"{sorted(self.template.fields)}",
                )
            self._write(cloud)
        self.count += len(cloud)

    def close(self) -> None:
        """Finish the file and rename it into place."""
        if self._closed:
            return
        try:
            with self._collect_warnings():
                if self.template is None:
                    raise FormatError(self.path, "nothing was written: the stream had no chunks")
                self._finish()
        except BaseException as error:
            self.abort(error)
            raise
        self._closed = True
        self._stack.close()
        for message, category in self._notes.items():
            warnings.warn(message, category, stacklevel=2)

    def abort(self, error: BaseException | None = None) -> None:
        """Remove everything written; ``path`` stays as it was."""
        if self._closed:
            return
        self._closed = True
        self._cleanup()
        failure = error if error is not None else RuntimeError("aborted")
        self._stack.__exit__(type(failure), failure, failure.__traceback__)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, kind: object, error: BaseException | None, traceback: object) -> None:
        if error is None:
            self.close()
        else:
            self.abort(error)

    @contextlib.contextmanager
    def _collect_warnings(self):
        """Warnings of the format's writer, said once at the end rather than once per chunk."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield
        for warning in caught:
            self._notes.setdefault(str(warning.message), warning.category)

    def _begin(self, cloud: PointCloud) -> None:
        pass

    def _write(self, cloud: PointCloud) -> None:
        raise NotImplementedError

    def _finish(self) -> None:
        pass

    def _cleanup(self) -> None:
        pass


class BodyFirstWriter(ChunkWriter):
    """Formats whose header states the point count: the records go to a body file, and at the
    end the header is written and the body copied after it."""

    def _begin(self, cloud: PointCloud) -> None:
        self.body_path = self.tmp.with_name(self.tmp.name + ".body")
        self.body: BinaryIO = open(self.body_path, "wb")  # noqa: SIM115 -- open across write calls, closed in _finish

    def _finish(self) -> None:
        self.body.close()
        with open(self.tmp, "wb") as out:
            out.write(self._header())
            with open(self.body_path, "rb") as body:
                shutil.copyfileobj(body, out, 1 << 24)
            self._trailer(out)
        self.body_path.unlink()

    def _cleanup(self) -> None:
        body = getattr(self, "body", None)
        if body is not None:
            body.close()
            self.body_path.unlink(missing_ok=True)

    def _header(self) -> bytes:
        raise NotImplementedError

    def _trailer(self, out: BinaryIO) -> None:
        pass
