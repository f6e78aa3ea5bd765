"""Read speed of pointfield's Leica PTX reader against straightforward numpy and pyarrow readers.

The claim (issue 18): on a 2-million-point single-scan PTX file with colours, pointfield reads
in at most 1.2x the time of a plain pyarrow reader (header by hand, ``pyarrow.csv.read_csv`` of
the rows, the transform applied, no-return cells made NaN), although it also puts the points in
the grid's row-major order and adds a ``scan_index``; and faster than ``numpy.loadtxt`` doing
the same. PDAL's ``readers.ptx`` is the peer the issue names: it is timed when a ``pdal``
command is on the PATH, else the record says why not.

The file is written as Leica Cyclone writes one: 2000 columns of 1000 rows (for 2 M points),
``x y z intensity red green blue`` with six decimals, a registered scan (its transform rotates
and moves it), 5% of the cells without a return. Times are the median of interleaved runs with
a warm page cache.

Run: ``make bench-ptx`` (or ``python benchmarks/bench_ptx.py --points 2000000``); the record goes
to ``benchmarks/records/ptx.json``.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pa_csv

import pointfield
from pointfield.clouds.formats.ascii import write_rows

from harness import Record, interleaved

ROWS = 1000  # scanner rows (points per column); columns = points / ROWS
TARGET_VS_PYARROW = 1.2


def make_file(path: Path, points: int) -> tuple[int, int]:
    """A single-scan PTX of ``points`` cells as a registered terrestrial scan; its grid."""
    rows = min(ROWS, points)
    columns = points // rows
    rng = np.random.default_rng(0)
    azimuth = np.repeat(np.linspace(0, 2 * np.pi, columns, endpoint=False), rows)
    elevation = np.tile(np.linspace(-0.8, 1.2, rows), columns)
    distance = rng.uniform(2, 80, columns * rows)
    xyz = np.stack(
        [
            distance * np.cos(elevation) * np.cos(azimuth),
            distance * np.cos(elevation) * np.sin(azimuth),
            distance * np.sin(elevation),
        ],
        axis=1,
    ).round(6)
    xyz[rng.random(len(xyz)) < 0.05] = 0.0  # cells without a return
    intensity = rng.random(len(xyz)).round(6)
    colors = rng.integers(0, 256, (len(xyz), 3), dtype=np.uint8)
    turn = 0.3
    c, s = float(np.cos(turn)), float(np.sin(turn))
    position = "512345.678 5401234.567 231.25"
    header = [
        str(columns), str(rows), position,
        f"{c!r} {s!r} 0", f"{-s!r} {c!r} 0", "0 0 1",
        f"{c!r} {s!r} 0 0", f"{-s!r} {c!r} 0 0", "0 0 1 0", f"{position} 1",
    ]
    with open(path, "wb") as file:
        file.write(("\n".join(header) + "\n").encode())
        write_rows(file, [*xyz.T, intensity, *colors.T])
    return rows, columns


def _header(path: Path) -> tuple[int, int, np.ndarray]:
    with open(path) as file:
        lines = [file.readline() for _ in range(10)]
    transform = np.array([[float(v) for v in line.split()] for line in lines[6:10]])
    return int(lines[0]), int(lines[1]), transform


def _cloud_from_rows(
    columns: list[np.ndarray], transform: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """points (transformed, NaN for no return), intensity and colours from the rows' columns."""
    xyz = np.stack(columns[:3], axis=1)
    no_return = ~xyz.any(axis=1)
    xyz = xyz @ transform[:3, :3] + transform[3, :3]
    xyz[no_return] = np.nan
    return xyz, np.asarray(columns[3]), np.stack(columns[4:7], axis=1).astype(np.uint8)


def read_pyarrow(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Header by hand, the rows by pyarrow's CSV reader, the transform, NaN for no return."""
    _, _, transform = _header(path)
    table = pa_csv.read_csv(
        path,
        read_options=pa_csv.ReadOptions(skip_rows=10, column_names=list("xyzirgb")),
        parse_options=pa_csv.ParseOptions(delimiter=" "),
        convert_options=pa_csv.ConvertOptions(
            column_types={name: pa.float64() for name in "xyzi"} | {name: pa.uint8() for name in "rgb"}
        ),
    )
    return _cloud_from_rows([column.to_numpy() for column in table.columns], transform)


def read_numpy(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The same with ``numpy.loadtxt``."""
    _, _, transform = _header(path)
    return _cloud_from_rows(list(np.loadtxt(path, skiprows=10).T), transform)


def read_pointfield(path: Path) -> pointfield.PointCloud:
    return pointfield.read(path)


def read_pdal(path: Path) -> None:
    """PDAL's reader, through the command line: PTX in, LAS out (its fastest writer)."""
    subprocess.run(["pdal", "translate", str(path), str(path.with_suffix(".las"))], check=True,
                   capture_output=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=2_000_000)
    parser.add_argument("--repeats", type=int, default=3, help="interleaved reads per reader (median)")
    args = parser.parse_args()

    record = Record(
        "ptx", "Leica PTX reading against numpy and pyarrow", issue="18",
        about=f"One registered scan of {args.points:,} cells (x y z intensity r g b, 6 decimals, 5% without a "
              "return), written as Leica Cyclone writes PTX. The pyarrow and numpy readers read the ten header "
              "lines by hand and the rows with pyarrow.csv.read_csv / numpy.loadtxt, apply the scan's transform and "
              "make no-return cells NaN; pointfield.read does that, puts the points in the grid's row-major order "
              "and adds scan_index. Reads alternate (median of the interleaved runs, warm page cache).")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scan.ptx"
        print(f"writing a {args.points:,}-point PTX scan ...", flush=True)
        rows, columns = make_file(path, args.points)
        size_mb = path.stat().st_size / 1e6
        cloud = read_pointfield(path)
        expected, _, colors = read_pyarrow(path)
        in_file_order = cloud.points.reshape(rows, columns, 3).transpose(1, 0, 2).reshape(-1, 3)
        assert np.allclose(in_file_order, expected, rtol=1e-12, atol=1e-9, equal_nan=True), \
            "pointfield's points differ from the pyarrow reader's"
        assert np.array_equal(cloud.fields["colors"].reshape(rows, columns, 3).transpose(1, 0, 2).reshape(-1, 3),
                              colors)
        del cloud, expected, colors, in_file_order

        contenders = {"numpy": lambda: read_numpy(path), "pyarrow": lambda: read_pyarrow(path),
                      "pointfield": lambda: read_pointfield(path)}
        if shutil.which("pdal"):
            contenders["pdal"] = lambda: read_pdal(path)
        else:
            record.note("PDAL is not installed here: no `pdal` command; PyPI has only its Python bindings (an "
                        "sdist that needs the PDAL C++ library) and Debian bookworm has no pdal package, so its "
                        "figure could not be had.")
        timings = interleaved(contenders, args.repeats)
    ours = timings["pointfield"].median
    rows_out = [[name, f"{timing.median:.3f}", f"{timing.spread:.0%}", f"{timing.median / ours:.2f}",
                 f"{args.points / timing.median / 1e6:.2f}"] for name, timing in timings.items()]
    record.table(["reader", "median s", "spread", "x pointfield's time", "M points / s"], rows_out,
                 title=f"{args.points:,} points, {size_mb:.1f} MB, median of {args.repeats} interleaved reads")
    ratio = ours / timings["pyarrow"].median
    record.figures.update({"points": args.points, "megabytes": size_mb, "grid": [rows, columns],
                           "ratio_to_pyarrow": ratio,
                           "timings": {name: timing.as_dict() for name, timing in timings.items()}})
    record.verdict(f"pointfield reads in at most {TARGET_VS_PYARROW}x the plain pyarrow reader's time",
                   ratio <= TARGET_VS_PYARROW, f"{ratio:.2f}x")
    record.verdict("pointfield reads faster than numpy.loadtxt", ours < timings["numpy"].median,
                   f"{timings['numpy'].median / ours:.1f}x faster")
    if "pdal" in timings:
        record.verdict("pointfield reads faster than `pdal translate` to LAS", ours < timings["pdal"].median,
                       f"{timings['pdal'].median / ours:.1f}x")
    return record.finish()


if __name__ == "__main__":
    sys.exit(main())
