"""The E57 physical file checked before libE57 reads anything by it.

libE57 trusts the physical header's lengths and each scan's declared record count when it
allocates; here each is checked against the bytes the file really has, so a hostile file is a
FormatError rather than gigabytes. (libE57 checks every page's CRC itself.)
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path

from pointfield.errors import FormatError

SIGNATURE = b"ASTM-E57"

# Physical file header (ASTM E2807 section 8): signature, version major / minor, physical file
# length, XML section offset, XML logical length, page size.
_FILE_HEADER = struct.Struct("<8sIIQQQQ")
_PAGE_SIZE = 1024  # E57 1.0 pages: 1020 bytes of data then a CRC-32C


def is_e57(head: bytes) -> bool:
    """True for E57 files: their physical header starts with ``ASTM-E57``."""
    return head.startswith(SIGNATURE)


def check_file_header(path: Path, size: int) -> None:
    """Check the physical header of the ``size``-byte file before libE57 reads the file by it."""
    with open(path, "rb") as file:
        head = file.read(_FILE_HEADER.size)
    if not is_e57(head):
        raise FormatError(path, f"not an E57 file: expected the signature {SIGNATURE!r}")
    if len(head) < _FILE_HEADER.size:
        raise FormatError(
            path, f"truncated: {size} bytes, the E57 header alone needs {_FILE_HEADER.size}"
        )
    _, major, minor, length, xml_offset, xml_length, page_size = _FILE_HEADER.unpack(head)
    if major != 1:
        raise FormatError(path, f"unsupported E57 version {major}.{minor}; expected 1.x")
    if page_size != _PAGE_SIZE:
        raise FormatError(
            path, f"page size {page_size}; E57 1.0 files have {_PAGE_SIZE}-byte pages"
        )
    if length != size or size % _PAGE_SIZE:
        raise FormatError(
            path,
            f"header says the file is {length} bytes; it is {size} (whole {_PAGE_SIZE}-byte pages)",
        )
    if not _FILE_HEADER.size <= xml_offset < size or xml_length > size:
        raise FormatError(
            path,
            f"XML section ({xml_length} bytes at {xml_offset}) lies outside the {size}-byte file",
        )


def check_record_counts(
    path: Path, counts: Sequence[int], record_bits: Sequence[int], size: int
) -> None:
    """Each record needs at least the bits of its elements, and every bit is in the file.

    ``counts[i]`` is the number of records scan i declares and ``record_bits[i]`` the bits its
    elements take, at least. Records are bit-packed without entropy coding, so a scan of N
    records with B bits each takes at least N * B bits of the file; all scans share the file, so
    their needs add up. (:func:`~pointfield.clouds.formats.binary.check_size` checks one
    declaration in whole bytes, which bit-packed records are not.) A record is counted as at
    least one bit, so that records of constant elements (zero bits) cannot claim unbounded
    counts either.
    """
    needed = sum(count * max(1, bits) for count, bits in zip(counts, record_bits, strict=True))
    if needed > 8 * size:
        raise FormatError(
            path, f"scans declare {list(counts)} records, more than the {size}-byte file can hold"
        )
