"""Numbers in text: the one tokenizer and number parser behind every ascii format (PLY, PCD, OFF,
XYZ / PTS / CSV), and the one writer of rows of numbers.

There are two ways in, a fast one and a general one, and a format tries them in that order:

- :func:`read_table` reads rows of numbers exactly one delimiter apart into typed columns with
  pyarrow's CSV reader (one thread: see read_table), several times faster than numpy (the
  README's dependency note). Integers stay exact, since each column is parsed as its own type.
  Anything else it refuses with a :class:`TableError` saying what it found.
- :func:`parse_numbers`, :func:`numbers_by_line` and :func:`rows_of_numbers` read every
  whitespace-separated number as float64 with numpy's tokenizer, whatever the spacing, and name
  the line of the first value that is not a number (or, for rows, of the first row too short or
  too long). :func:`single_spaced` rewrites irregular spacing so that text the fast way
  refused for its spacing alone can take the fast way after all, keeping the column types.

:func:`skip_lines` finds where a declared number of lines ends (counting newlines in large
chunks) so that a count in a header is checked against the text before anything is allocated.
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Sequence
from typing import BinaryIO

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv

from pointfield.errors import FormatError

# Lines are counted with bytes.count in windows of up to this size (a per-byte array of the
# whole text would cost far more).
LINE_SCAN_CHUNK = 1 << 22

# Bytes that separate numbers for numpy's tokenizer: the C locale's isspace().
_WHITESPACE = np.zeros(256, bool)
_WHITESPACE[[ord(c) for c in " \t\n\r\v\f"]] = True

_RUNS_OF_SPACE = re.compile(rb"[ \t\r\f\v]+")
_SPACE_AROUND_NEWLINE = re.compile(rb" ?\n ?")


class TableError(ValueError):
    """Text that is not rows of the declared columns, one delimiter apart; says what was found."""


# ---------------------------------------------------------------------------------------------
# The fast way: typed columns by pyarrow


def read_table(
    data: bytes | bytearray | memoryview,
    column_types: Sequence[np.dtype | None],
    delimiter: str = " ",
) -> list[np.ndarray | None]:
    """The columns of ``data``, rows of ``len(column_types)`` values one ``delimiter`` apart.

    Each column is parsed as its dtype (float16 through float32, which holds every float16
    text exactly); a None type leaves that column unparsed and returns None for it (padding).
    ``nan``, ``inf`` and ``-inf`` are floats. Lines may end in CRLF, blank lines are skipped,
    and when the first line ends in a delimiter every line may (what follows that delimiter is
    not read: a line with one value more than the first, and no closing delimiter, passes).
    Raises :class:`TableError` for anything else: another delimiter (two spaces, a tab), a row
    of another length, a value that is not a number of its column's type.
    """
    first_end = bytes(data[:1 << 16]).find(b"\n")
    first_line = bytes(data[: first_end if first_end >= 0 else 1 << 16]).rstrip(b"\r")
    separator = delimiter.encode()
    tokens = first_line.split(separator)
    trailing = len(tokens) > 1 and tokens[-1] == b""
    if trailing:
        tokens.pop()
    if b"" in tokens or (delimiter == " " and b"\t" in first_line):
        raise TableError(f"the first line is not values one {delimiter!r} apart")
    names = [f"c{i}" for i in range(len(column_types))]
    parsed = {
        name: pa.from_numpy_dtype(_parsed_dtype(dtype))
        for name, dtype in zip(names, column_types, strict=True)
        if dtype is not None
    }
    if trailing:
        # The empty column after the delimiter that closes each line, left unparsed: checking
        # that it is empty on every line costs a tenth of the parse.
        names.append("end")
    try:
        # One thread: pyarrow 26's CSV thread pool, once used, aborts the interpreter at exit in about
        # one process in five when torch is loaded too ("terminate called without an active
        # exception", status 134). The price, on two cores (`make bench-ptx`, 2 M points, quiet):
        # 0.524 s against 0.352 s for pyarrow's threaded default, still 4.7x faster than loadtxt.
        table = pa_csv.read_csv(
            pa.py_buffer(data),
            read_options=pa_csv.ReadOptions(column_names=names, use_threads=False),
            parse_options=pa_csv.ParseOptions(
                delimiter=delimiter, quote_char=False, double_quote=False
            ),
            convert_options=pa_csv.ConvertOptions(
                column_types=parsed,
                include_columns=list(parsed),
                null_values=[],
                strings_can_be_null=False,
            ),
        )
    except pa.ArrowException as error:
        lines = str(error).strip().splitlines()
        raise TableError(lines[0][:200] if lines else type(error).__name__) from None
    columns = iter(table.columns)
    return [
        None if dtype is None else next(columns).to_numpy().astype(dtype, copy=False)
        for dtype in column_types
    ]


def _parsed_dtype(dtype: np.dtype) -> np.dtype:
    """The type pyarrow parses a column of ``dtype`` as: native order; no float16 parser."""
    dtype = np.dtype(dtype).newbyteorder("=")
    return np.dtype(np.float32) if dtype == np.float16 else dtype


def single_spaced(data: bytes | bytearray) -> bytes:
    """``data`` with every run of spaces and tabs made one space, none at the ends of lines."""
    spaced = _RUNS_OF_SPACE.sub(b" ", data)
    return _SPACE_AROUND_NEWLINE.sub(b"\n", spaced).strip()


# ---------------------------------------------------------------------------------------------
# The general way: every number as float64 by numpy


def parse_numbers(
    text: bytes, path: str | os.PathLike[str], first_line: int = 1
) -> np.ndarray:
    """Every whitespace-separated number in ``text``, as float64 ``(T,)`` in reading order.

    Raises FormatError naming the line (``first_line`` being the first line of ``text``) and
    the text of the first value that is not a number.
    """
    values = _numbers(text)
    if values is None:
        raise _not_a_number(text, path, first_line)
    return values


def numbers_by_line(
    text: bytes, path: str | os.PathLike[str], first_line: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every whitespace-separated number in ``text``, and which line each comes from.

    Returns ``(values, counts, line_numbers, line_starts)``: ``values`` (T,) float64 in reading
    order; then for each non-blank line, in order, ``counts`` (L,) how many numbers it holds,
    ``line_numbers`` (L,) its line number (``first_line`` for the first line of ``text``) and
    ``line_starts`` (L,) the byte offset of its first number. Vectorised: no Python loop over
    lines, so a 100k-line mesh parses in milliseconds. Raises FormatError naming the line of
    the first value that is not a number.
    """
    token_starts, token_lines = _tokens(text)
    first_of_line = np.flatnonzero(np.diff(token_lines, prepend=-1))
    counts = np.diff(np.append(first_of_line, len(token_starts)))
    values = _numbers(text)
    # numpy can read one token as two numbers ("1-2"); counting tokens catches that too.
    if values is None or len(values) != len(token_starts):
        raise _not_a_number(text, path, first_line)
    return (
        values,
        counts,
        token_lines[first_of_line] + first_line,
        token_starts[first_of_line],
    )


def rows_of_numbers(
    text: bytes, width: int, path: str | os.PathLike[str], first_line: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """``text`` as rows of ``width`` numbers: the ``(N, width)`` float64 table and each row's line
    number ``(N,)`` (``first_line`` being the first line of ``text``); blank lines are skipped.

    The general way's counterpart of :func:`read_table` for rows of one length. Raises
    FormatError naming the first line that holds another number of values, or that holds a
    value that is not a number.
    """
    values, counts, line_numbers, _ = numbers_by_line(text, path, first_line)
    wrong = np.flatnonzero(counts != width)
    if len(wrong):
        raise FormatError(
            path,
            f"line {line_numbers[wrong[0]]} has {counts[wrong[0]]} values; the rows before it "
            f"have {width}",
        )
    return values.reshape(-1, width), line_numbers


def _numbers(text: bytes) -> np.ndarray | None:
    """numpy's parse of the whole text; None when some token is not a number."""
    if not text or text.isspace():
        return np.zeros(0)  # numpy reads whitespace alone as [-1.0]
    with warnings.catch_warnings():
        # numpy before 2.0 stops at the first token that is not a number and only warns.
        warnings.simplefilter("error", DeprecationWarning)
        try:
            return np.fromstring(text, sep=" ")
        except (DeprecationWarning, ValueError):
            return None


def _tokens(text: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Byte offset of every token's first byte, and the index of its line from 0."""
    raw = np.frombuffer(text, np.uint8)
    is_space = _WHITESPACE[raw]
    token_starts = np.flatnonzero(~is_space & np.concatenate(([True], is_space[:-1])))
    newlines = np.flatnonzero(raw == ord("\n"))
    return token_starts, np.searchsorted(newlines, token_starts)


def _not_a_number(text: bytes, path: str | os.PathLike[str], first_line: int) -> FormatError:
    """The error for the first token that numpy does not read as exactly one number.

    Chunks of tokens are parsed whole and only the first failing chunk token by token, so even
    the error path of a large text stays fast.
    """
    token_starts, token_lines = _tokens(text)
    chunk = 4096
    for a in range(0, len(token_starts), chunk):
        b = min(a + chunk, len(token_starts))
        stop = token_starts[b] if b < len(token_starts) else len(text)
        piece = text[token_starts[a] : stop]
        if _parses_as(piece, b - a):
            continue
        for i, token in enumerate(piece.split(), a):
            if not _parses_as(token, 1):
                line = int(token_lines[i]) + first_line
                return FormatError(path, f"line {line}: {token[:40]!r} is not a number")
    return FormatError(path, f"line {first_line}: {text[:40]!r} is not a number")


def _parses_as(text: bytes, count: int) -> bool:
    values = _numbers(text)
    return values is not None and len(values) == count


# ---------------------------------------------------------------------------------------------
# Lines


def skip_lines(data: bytes | bytearray, start: int, count: int) -> tuple[int, int]:
    """``(end, found)``: the offset just past ``count`` lines from ``start``, and how many lines
    there are (``count``, or fewer when the data ends first; then ``end`` is its end).

    A last line without a newline counts when it holds something.
    """
    needed, position, size = count, start, len(data)
    # Windows start near the lines' likely size and double, so a few lines cost little and
    # many are counted in big strides.
    window = max(4096, min(count * 16, LINE_SCAN_CHUNK))
    while position < size and needed:
        stop = min(position + window, size)
        found = data.count(b"\n", position, stop)
        if found >= needed:
            return _nth_line_end(data, position, stop, needed), count
        needed -= found
        position = stop
        window = min(window * 2, LINE_SCAN_CHUNK)
    if not needed:
        return start if count == 0 else size, count
    last_line_start = max(data.rfind(b"\n", start) + 1, start)
    if needed == 1 and data[last_line_start:].strip():
        return size, count
    return size, count - needed


def _nth_line_end(data: bytes | bytearray, low: int, high: int, needed: int) -> int:
    """Offset just past the ``needed``-th newline in ``data[low:high]``, which holds at least
    that many: bisection while the span is long, then a step per line."""
    while high - low > 256:
        middle = (low + high) // 2
        found = data.count(b"\n", low, middle)
        if found >= needed:
            high = middle
        else:
            needed -= found
            low = middle
    end = low
    for _ in range(needed):
        end = data.index(b"\n", end) + 1
    return end


# ---------------------------------------------------------------------------------------------
# Writing


def write_rows(
    file: BinaryIO,
    columns: Sequence[np.ndarray],
    delimiter: str = " ",
    floats_as: type[np.floating] | None = None,
) -> None:
    """Write ``(N,)`` columns as N lines of numbers, by pyarrow's CSV writer.

    Each column is printed in its own dtype: floats in the shortest text that reads back as the
    same value of that dtype (NaN and infinities as ``nan``, ``inf``, ``-inf``), integers as
    integers, booleans as 0 / 1. ``floats_as`` prints every float column as that type instead
    (``np.float64`` for formats whose readers give float64: a float32 then prints as its exact
    float64 value, where its own shortest text would read back as another float64).
    """
    if not columns:
        return
    arrays = {}
    for i, values in enumerate(columns):
        if floats_as is not None and values.dtype.kind == "f":
            values = values.astype(floats_as, copy=False)
        elif values.dtype.kind == "b":
            values = values.astype(np.uint8)
        values = values.astype(values.dtype.newbyteorder("="), copy=False)
        arrays[f"c{i}"] = pa.array(np.ascontiguousarray(values))
    pa_csv.write_csv(
        pa.table(arrays),
        file,
        pa_csv.WriteOptions(include_header=False, delimiter=delimiter, quoting_style="none"),
    )
