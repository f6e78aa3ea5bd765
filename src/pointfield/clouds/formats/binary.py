"""Packed binary records: the one reader of fixed-size records (a structured numpy dtype over a
byte range of a file, in either byte order) and the one size check every binary format makes.

A header's counts are claims: a file of a few hundred bytes can declare 10**12 points. Before
anything is allocated by such a count, :func:`check_size` compares the bytes the claim needs,
``count * record size``, with the bytes the file really has, and refuses with a FormatError
naming the file, what declared the count and both sizes.

Records are then read through a read-only map of the file (:func:`map_file`,
:func:`read_records`): no copy from the page cache is made (small files excepted), and each
field is copied once, straight into its final array, when the format turns records into a
cloud.
"""

from __future__ import annotations

import mmap
import os
from collections.abc import Sequence
from typing import BinaryIO

import numpy as np

from pointfield.errors import FormatError

# Files smaller than this are read rather than mapped: mapping and its page faults cost more
# than the copy (about 30 us on a 32 KiB file), and the copy is small.
MAP_MIN_BYTES = 1 << 20

# A field of a record: its name, its dtype, and the shape of a subarray field ((K,) for K values).
RecordField = tuple[str, np.dtype] | tuple[str, np.dtype, tuple[int, ...]]


def check_size(
    path: str | os.PathLike[str],
    what: str,
    count: int,
    record_size: int,
    available: int,
    *,
    unit: str = "records",
    at_least: bool = False,
) -> None:
    """Refuse ``count`` records of ``record_size`` bytes when only ``available`` bytes hold them.

    ``what`` names the declaration (``"header"``, ``"element 'vertex'"``) and ``unit`` what it
    counts; ``at_least`` says that records are at least ``record_size`` bytes (lists of varying
    length follow). For example: ``header declares 1065 points of 34 bytes: it needs 36210
    bytes but only 1000 follow``.
    """
    needed = count * record_size
    if needed > available:
        size = f"at least {record_size}" if at_least else f"{record_size}"
        raise FormatError(
            path,
            f"{what} declares {count} {unit} of {size} bytes: it needs {needed} bytes but only "
            f"{available} follow",
        )


def map_file(file: BinaryIO, head: bytes = b"") -> mmap.mmap | bytes:
    """The whole open ``file`` as a read-only buffer: mapped, or read when it is small.

    ``head``, the file's first bytes when the caller has read them (a header), is the buffer
    itself when it is the whole file. Arrays viewing a map keep it alive; it is unmapped when
    the last one is gone.
    """
    size = os.fstat(file.fileno()).st_size
    if len(head) == size:
        return head
    if size < MAP_MIN_BYTES:
        file.seek(0)
        return file.read()
    return mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ)


def record_dtype(
    fields: Sequence[RecordField],
    byte_order: str,
    offsets: Sequence[int] | None = None,
    itemsize: int | None = None,
) -> np.dtype:
    """The structured dtype of one record: ``fields`` in order, every value in ``byte_order``
    (``"<"``, ``">"`` or ``"="``), packed without alignment unless ``offsets`` and
    ``itemsize`` place the fields (to skip padding bytes)."""
    names = [field[0] for field in fields]
    formats = [
        np.dtype(field[1]).newbyteorder(byte_order)
        if len(field) == 2 or not field[2]  # type: ignore[misc]
        else np.dtype((np.dtype(field[1]).newbyteorder(byte_order), field[2]))  # type: ignore[misc]
        for field in fields
    ]
    if offsets is None:
        return np.dtype(list(zip(names, formats, strict=True)))
    layout = {"names": names, "formats": formats, "offsets": list(offsets)}
    if itemsize is not None:
        layout["itemsize"] = itemsize
    return np.dtype(layout)


def read_records(
    buffer: mmap.mmap | bytes | bytearray, dtype: np.dtype, count: int, offset: int = 0
) -> np.ndarray:
    """``count`` records of ``dtype`` starting at byte ``offset`` of ``buffer``, in native byte
    order: a read-only view when the file's order is native, else one native copy.

    The caller has checked the size (:func:`check_size`); a buffer too short is a bug here.
    """
    if count == 0:
        return np.zeros(0, dtype.newbyteorder("="))
    records = np.frombuffer(buffer, dtype, count, offset)
    # Comparing with the native dtype looks inside subarray fields, which dtype.isnative does not.
    native = dtype.newbyteorder("=")
    return records if dtype == native else records.astype(native)


# ---------------------------------------------------------------------------------------------
# Records of varying size (lists): values at computed byte positions


def item_positions(first: np.ndarray, lengths: np.ndarray, step: int) -> np.ndarray:
    """Positions of every list item, flat: record i contributes ``first[i] + step * j`` for
    ``j < lengths[i]``."""
    total = int(lengths.sum())
    record_of_item = np.repeat(np.arange(len(lengths)), lengths)
    index_in_list = np.arange(total) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    return first[record_of_item] + step * index_in_list


def gather(data: np.ndarray, positions: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Values of ``dtype`` starting at the byte ``positions`` of ``data`` (uint8), in native
    byte order."""
    size = dtype.itemsize
    raw = data[positions[:, None] + np.arange(size)] if size > 1 else data[positions]
    values = np.ascontiguousarray(raw).view(dtype).reshape(len(positions))
    return values.astype(dtype.newbyteorder("="))


def scatter(out: np.ndarray, positions: np.ndarray, values: np.ndarray) -> None:
    """Write ``values`` at the byte ``positions`` of ``out`` (uint8), in their own byte order:
    the inverse of :func:`gather`."""
    size = values.dtype.itemsize
    raw = np.ascontiguousarray(values).view(np.uint8).reshape(len(values), size)
    out[positions[:, None] + np.arange(size)] = raw
