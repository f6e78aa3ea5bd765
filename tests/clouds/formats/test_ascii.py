"""The shared ascii machinery: the fast typed table reader, the general number parser, lines."""

from __future__ import annotations

import io

import numpy as np
import pytest

from pointfield import FormatError
from pointfield.clouds.formats.ascii import (
    TableError,
    numbers_by_line,
    parse_numbers,
    read_table,
    single_spaced,
    skip_lines,
    write_rows,
)

F8, I8, U1 = np.dtype("f8"), np.dtype("i8"), np.dtype("u1")


def test_table_columns_keep_their_types_and_integers_stay_exact():
    big = 2**62 + 1  # not a float64
    x, n, c = read_table(f"1.5 {big} 7\n-2 3 255\n".encode(), [F8, I8, U1])
    assert (x.dtype, n.dtype, c.dtype) == (F8, I8, U1)
    assert n[0] == big and list(c) == [7, 255]


def test_table_reads_float16_columns():
    (values,) = read_table(b"0.5\n65504\n", [np.dtype("f2")])
    assert values.dtype == np.float16 and list(values) == [0.5, 65504]


def test_table_skips_columns_without_a_type():
    x, padding, z = read_table(b"1 word 3\n", [F8, None, F8])
    assert padding is None and (x[0], z[0]) == (1, 3)


def test_table_accepts_a_delimiter_closing_every_line():
    x, y = read_table(b"1,2,\n3,4,\n", [F8, F8], delimiter=",")
    assert list(x) == [1, 3] and list(y) == [2, 4]


def test_table_refuses_a_line_longer_than_the_first_with_its_closing_delimiter():
    with pytest.raises(TableError):
        read_table(b"1 2 \n3 4 5 \n", [F8, F8])


@pytest.mark.parametrize("text", [b"1  2\n", b"1\t2\n", b"1 2\n3\n", b"1 x\n"])
def test_table_refuses_anything_but_one_delimiter_between_numbers(text):
    with pytest.raises(TableError):
        read_table(text, [F8, F8])


def test_single_spacing_makes_irregular_text_a_table():
    assert single_spaced(b"  1 \t 2  \r\n3    4 \n") == b"1 2\n3 4"


def test_numbers_are_read_whatever_the_spacing():
    np.testing.assert_array_equal(parse_numbers(b" 1\t2\n\n  3 nan ", "f.txt"), [1, 2, 3, np.nan])


def test_whitespace_alone_holds_no_numbers():
    assert parse_numbers(b" \n \n", "f.txt").size == 0


def test_a_value_that_is_not_a_number_is_named_with_its_line():
    with pytest.raises(FormatError, match=r"f\.txt: line 12: b'2x' is not a number"):
        parse_numbers(b"1 2\n\n3 2x\n", "f.txt", first_line=10)


def test_numbers_by_line_counts_each_line():
    values, counts, lines, starts = numbers_by_line(b"1 2 3\n\n4 5\n", "f.txt")
    assert list(values) == [1, 2, 3, 4, 5] and list(counts) == [3, 2]
    assert list(lines) == [1, 3] and list(starts) == [0, 7]


def test_skip_lines_finds_the_end_of_a_count_of_lines():
    data = b"a\nb\nc\nd\n"
    assert skip_lines(data, 2, 2) == (6, 2)


def test_skip_lines_says_how_many_lines_there_were_when_too_few():
    assert skip_lines(b"a\nb\n", 0, 5) == (4, 2)


def test_skip_lines_counts_a_last_line_without_newline():
    assert skip_lines(b"a\nb", 0, 2) == (3, 2)


def test_rows_written_read_back_as_the_same_values():
    x = np.array([0.1, np.nan, -np.inf], np.float32)
    n = np.array([-(2**40), 0, 7], np.int64)
    file = io.BytesIO()
    write_rows(file, [x, n])
    back_x, back_n = read_table(file.getvalue(), [x.dtype, n.dtype])
    np.testing.assert_array_equal(back_x, x)
    np.testing.assert_array_equal(back_n, n)


def test_rows_can_print_float32_as_its_exact_float64():
    file = io.BytesIO()
    write_rows(file, [np.array([0.1], np.float32)], floats_as=np.float64)
    assert float(file.getvalue()) == float(np.float32(0.1))
