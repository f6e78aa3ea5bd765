"""E57: all scans merged in one frame with a scan index, fields under their canonical names,
round trips exact for what pointfield writes, hostile files raise FormatError naming the file."""

from __future__ import annotations

import re
import struct
import sys
import uuid
import warnings

import numpy as np
import pytest

import pointfield
from pointfield import FormatError, PointCloud, PointfieldError
from pointfield.clouds.cloud import same_fields

pye57 = pytest.importorskip("pye57")
libe57 = pye57.libe57

COUNTS = {
    "pye57_testWithNormals.e57": 2,
    "pye57_pumpAVisualReferenceImage.e57": 155201,
    "pdal_A4.e57": 4,
    "pdal_A_B.e57": 6,
}
CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")


def e57_file(shared_data, name):
    return shared_data / "e57" / name


def raw_elements(path, scan, names):
    """Elements of one scan as libE57 stores them, read without pointfield."""
    e57 = pye57.E57(str(path))
    header = e57.get_header(scan)
    buffers = libe57.VectorSourceDestBuffer()
    arrays = {name: np.empty(header.point_count, np.float64) for name in names}
    for name, array in arrays.items():
        buffers.append(
            libe57.SourceDestBuffer(e57.image_file, name, array, header.point_count, True, True)
        )
    reader = header.points.reader(buffers)
    reader.read()
    reader.close()
    e57.close()
    return arrays


def write_raw_scans(path, scans):
    """Write scans with libE57 directly: each a dict of element -> (values, node), plus a pose."""
    e57 = pye57.E57(str(path), mode="w")
    imf = e57.image_file
    imf.extensionsAdd("nor", "http://www.libe57.org/E57_NOR_surface_normals.txt")
    for elements, pose in scans:
        scan = libe57.StructureNode(imf)
        scan.set("guid", libe57.StringNode(imf, f"{{{uuid.uuid4()}}}"))
        if pose is not None:
            rotation, translation = pose
            pose_node = libe57.StructureNode(imf)
            rotation_node = libe57.StructureNode(imf)
            for axis, value in zip("wxyz", rotation, strict=True):
                rotation_node.set(axis, libe57.FloatNode(imf, float(value)))
            translation_node = libe57.StructureNode(imf)
            for axis, value in zip("xyz", translation, strict=True):
                translation_node.set(axis, libe57.FloatNode(imf, float(value)))
            pose_node.set("rotation", rotation_node)
            pose_node.set("translation", translation_node)
            scan.set("pose", pose_node)
        prototype = libe57.StructureNode(imf)
        for name, (_, node) in elements.items():
            prototype.set(name, node(imf))
        points = libe57.CompressedVectorNode(imf, prototype, libe57.VectorNode(imf, True))
        scan.set("points", points)
        e57.data3d.append(scan)
        count = len(next(iter(elements.values()))[0])
        buffers = libe57.VectorSourceDestBuffer()
        for name, (values, _) in elements.items():
            buffers.append(libe57.SourceDestBuffer(imf, name, values, count, True, True))
        writer = points.writer(buffers)
        writer.write(count)
        writer.close()
    e57.close()


def double(imf):
    return libe57.FloatNode(imf, 0.0, libe57.E57_DOUBLE)


def state(imf):
    return libe57.IntegerNode(imf, 0, 0, 2)


# --- reading ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", COUNTS)
def test_every_e57_file_reads_with_its_manifest_count(shared_data, name):
    cloud = pointfield.read(e57_file(shared_data, name))
    assert len(cloud) == COUNTS[name]
    assert cloud.metadata["format"] == "e57"
    assert cloud.metadata["encoding"] == "e57"


@pytest.mark.parametrize("name", COUNTS)
def test_points_are_float64_and_equal_to_the_stored_coordinates(shared_data, name):
    path = e57_file(shared_data, name)
    cloud = pointfield.read(path)
    assert cloud.points.dtype == np.float64
    scans = len(cloud.metadata["e57_scans"])
    expected = np.concatenate(
        [
            np.stack(list(raw_elements(path, scan, CARTESIAN).values()), axis=1)
            for scan in range(scans)
        ]
    )
    np.testing.assert_array_equal(cloud.points, expected)


def test_scans_are_merged_with_a_scan_index(shared_data):
    cloud = pointfield.read(e57_file(shared_data, "pdal_A_B.e57"))
    assert cloud.fields["scan_index"].dtype == np.uint8
    np.testing.assert_array_equal(cloud.fields["scan_index"], [0, 0, 1, 1, 1, 1])
    assert [scan["points"] for scan in cloud.metadata["e57_scans"]] == [2, 4]
    assert cloud.metadata["e57_scans"][0]["name"] == "B2 - Cloud"


def test_structured_scan_fields_keep_their_names_and_natural_dtypes(shared_data):
    path = e57_file(shared_data, "pye57_pumpAVisualReferenceImage.e57")
    fields = pointfield.read(path).fields
    assert (fields["colors"].dtype, fields["colors"].shape) == (np.uint8, (155201, 3))
    assert fields["intensity"].dtype == np.float64  # a scaled integer in the file
    assert fields["rowIndex"].dtype == np.uint16 and fields["columnIndex"].dtype == np.uint16
    assert fields["cartesianInvalidState"].dtype == np.uint8
    raw = pye57.E57(str(path)).read_scan_raw(0)
    for axis, name in enumerate(("colorRed", "colorGreen", "colorBlue")):
        np.testing.assert_array_equal(fields["colors"][:, axis], raw[name])
    np.testing.assert_array_equal(fields["rowIndex"], raw["rowIndex"])


def test_normals_extension_becomes_normals(shared_data):
    path = e57_file(shared_data, "pye57_testWithNormals.e57")
    normals = pointfield.read(path).fields["normals"]
    assert (normals.dtype, normals.shape) == (np.float32, (2, 3))
    expected = raw_elements(path, 0, ("nor:normalX", "nor:normalY", "nor:normalZ"))
    np.testing.assert_array_equal(normals, np.stack(list(expected.values()), axis=1))


def test_each_scans_pose_is_applied_as_pye57_applies_it(tmp_path):
    rng = np.random.default_rng(1)
    path = tmp_path / "posed.e57"
    e57 = pye57.E57(str(path), mode="w")
    rotations = [np.array([0.9, 0.1, -0.3, 0.2]), np.array([1.0, 0.0, 0.0, 0.0])]
    for scan, rotation in enumerate(rotations):
        data = {name: rng.normal(size=10) for name in CARTESIAN}
        e57.write_scan_raw(
            data,
            rotation=rotation / np.linalg.norm(rotation),
            translation=np.array([10.0, -5, 2]) * (scan + 1),
        )
    e57.close()
    reference = pye57.E57(str(path))
    expected = np.concatenate(
        [
            np.stack(
                [reference.read_scan(i, ignore_missing_fields=True)[n] for n in CARTESIAN], axis=1
            )
            for i in range(2)
        ]
    )
    np.testing.assert_allclose(pointfield.read(path).points, expected, rtol=0, atol=1e-12)


def test_normals_are_rotated_with_their_scan(tmp_path):
    path = tmp_path / "normals.e57"
    quarter_turn_about_z = (np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4))
    elements = {
        **{name: (np.array([1.0, 0.0]), double) for name in CARTESIAN},
        "nor:normalX": (np.array([1.0, 0.0]), double),
        "nor:normalY": (np.array([0.0, 1.0]), double),
        "nor:normalZ": (np.array([0.0, 0.0]), double),
    }
    write_raw_scans(path, [(elements, (quarter_turn_about_z, (0.0, 0.0, 5.0)))])
    cloud = pointfield.read(path)
    np.testing.assert_allclose(cloud.points, [[-1, 1, 6], [0, 0, 5]], atol=1e-12)
    np.testing.assert_allclose(cloud.fields["normals"], [[0, 1, 0], [-1, 0, 0]], atol=1e-12)


def test_spherical_scans_are_converted_to_cartesian(tmp_path):
    path = tmp_path / "spherical.e57"
    distance = np.array([2.0, 3.0, 4.0])
    azimuth = np.array([0.0, np.pi / 2, 0.3])
    elevation = np.array([0.0, 0.0, np.pi / 2])
    elements = {
        "sphericalRange": (distance, double),
        "sphericalAzimuth": (azimuth, double),
        "sphericalElevation": (elevation, double),
    }
    write_raw_scans(path, [(elements, None)])
    cloud = pointfield.read(path)
    np.testing.assert_allclose(cloud.points, [[2, 0, 0], [0, 3, 0], [0, 0, 4]], atol=1e-12)
    np.testing.assert_array_equal(cloud.fields["sphericalRange"], distance)


def test_points_marked_invalid_become_nan_rows_and_keep_their_state(tmp_path):
    path = tmp_path / "invalid.e57"
    elements = {name: (np.arange(3.0), double) for name in CARTESIAN}
    elements["cartesianInvalidState"] = (np.array([0, 1, 2], np.int8), state)
    write_raw_scans(path, [(elements, None)])
    cloud = pointfield.read(path)
    assert cloud.nan_count == 2
    np.testing.assert_array_equal(cloud.points[0], [0, 0, 0])
    np.testing.assert_array_equal(cloud.fields["cartesianInvalidState"], [0, 1, 2])


def test_scans_without_a_field_get_nan_or_zero_there(tmp_path):
    path = tmp_path / "uneven.e57"
    first = {name: (np.zeros(2), double) for name in CARTESIAN}
    first["intensity"] = (np.array([0.5, 0.25]), double)
    second = {name: (np.ones(1), double) for name in CARTESIAN}
    second["rowIndex"] = (np.array([7], np.int16), lambda imf: libe57.IntegerNode(imf, 0, 0, 1000))
    write_raw_scans(path, [(first, None), (second, None)])
    fields = pointfield.read(path).fields
    np.testing.assert_array_equal(fields["intensity"], [0.5, 0.25, np.nan])
    np.testing.assert_array_equal(fields["rowIndex"], [0, 0, 7])
    assert fields["rowIndex"].dtype == np.uint16


# --- round trips ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", COUNTS)
def test_real_files_round_trip(shared_data, tmp_path, name):
    cloud = pointfield.read(e57_file(shared_data, name))
    path = tmp_path / "copy.e57"
    pointfield.write(path, cloud)
    back = pointfield.read(path)
    np.testing.assert_array_equal(back.points, cloud.points)
    assert same_fields(back.fields, cloud.fields)
    assert [scan["name"] for scan in back.metadata["e57_scans"]] == [
        scan["name"] for scan in cloud.metadata["e57_scans"]
    ]


def test_generated_cloud_round_trips_every_field_exactly(tmp_path):
    rng = np.random.default_rng(0)
    n = 300
    points = rng.normal(size=(n, 3))
    points[3] = np.nan
    cloud = PointCloud(
        points,
        {
            "colors": rng.integers(0, 65535, (n, 4)).astype(np.uint16),
            "normals": rng.normal(size=(n, 3)).astype(np.float16),
            "intensity": rng.integers(0, 5000, n).astype(np.uint16),
            "label": rng.integers(-(2**40), 2**40, n),
            "count": rng.integers(0, 2**32 - 1, n).astype(np.uint32),
            "big": rng.integers(0, 2**62, n).astype(np.uint64),
            "feature": rng.normal(size=(n, 5)).astype(np.float32),
            "flag": rng.random(n) > 0.5,
            "rowIndex": rng.integers(0, 100, n).astype(np.int32),
            "timeStamp": rng.random(n),
            "odd name ü": rng.random(n),
            "scan_index": rng.integers(0, 3, n).astype(np.int16),
        },
    )
    path = tmp_path / "cloud.e57"
    pointfield.write(path, cloud)
    back = pointfield.read(path)
    grouped = cloud.select(np.argsort(cloud.fields["scan_index"], kind="stable"))
    np.testing.assert_array_equal(back.points, grouped.points)
    assert same_fields(back.fields, grouped.fields)
    assert len(back.metadata["e57_scans"]) == 3


def test_standard_elements_are_visible_to_other_readers(tmp_path):
    rng = np.random.default_rng(2)
    cloud = PointCloud(
        rng.normal(size=(5, 3)),
        {
            "colors": rng.integers(0, 256, (5, 3), dtype=np.uint8),
            "intensity": rng.random(5).astype(np.float32),
        },
    )
    path = tmp_path / "cloud.e57"
    pointfield.write(path, cloud)
    raw = pye57.E57(str(path)).read_scan_raw(0, ignore_unsupported_fields=True)
    np.testing.assert_array_equal(raw["colorRed"], cloud.fields["colors"][:, 0])
    np.testing.assert_array_equal(raw["intensity"], cloud.fields["intensity"])
    np.testing.assert_array_equal(raw["cartesianX"], cloud.points[:, 0])


def test_a_cloud_without_scan_index_does_not_gain_one(tmp_path):
    cloud = PointCloud(np.arange(12.0).reshape(4, 3), {"intensity": np.arange(4.0)})
    pointfield.write(tmp_path / "cloud.e57", cloud)
    assert pointfield.read(tmp_path / "cloud.e57").fields.keys() == {"intensity"}


def test_float32_points_come_back_as_float64_with_their_values(tmp_path):
    points = np.random.default_rng(3).normal(size=(12, 3)).astype(np.float32)
    pointfield.write(tmp_path / "cloud.e57", PointCloud(points, shape=(3, 4)))
    back = pointfield.read(tmp_path / "cloud.e57")
    assert back.points.dtype == np.float64
    np.testing.assert_array_equal(back.points, points.astype(np.float64))
    assert back.shape == (3, 4)


def test_empty_cloud_round_trips(tmp_path):
    pointfield.write(tmp_path / "empty.e57", PointCloud(np.zeros((0, 3))))
    assert len(pointfield.read(tmp_path / "empty.e57")) == 0


def test_fields_e57_cannot_hold_are_named_in_a_warning(tmp_path):
    cloud = PointCloud(np.zeros((2, 3)), {"name": np.array(["a", "b"])})
    with pytest.warns(UserWarning, match="E57 cannot hold these fields: name"):
        pointfield.write(tmp_path / "cloud.e57", cloud)


def test_missing_pye57_names_the_extra_to_install(shared_data, monkeypatch):
    monkeypatch.setitem(sys.modules, "pye57", None)
    with pytest.raises(PointfieldError, match=r"pip install 'pointfield\[e57\]'"):
        pointfield.read(e57_file(shared_data, "pdal_A4.e57"))


# --- hostile files ----------------------------------------------------------------------------


PAGE, PAGE_DATA = 1024, 1020


def crc32c(data: bytes) -> int:
    crc = 0xFFFFFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ (0x82F63B78 if crc & 1 else 0)
    return crc ^ 0xFFFFFFFF


def with_valid_checksums(logical: bytes, xml_length: int) -> bytes:
    """Pages of 1020 bytes + CRC-32C from the logical content, header lengths updated."""
    pages = [
        logical[i : i + PAGE_DATA].ljust(PAGE_DATA, b"\0")
        for i in range(0, len(logical), PAGE_DATA)
    ]
    data = bytearray()
    for i, page in enumerate(pages):
        page = bytearray(page)
        if i == 0:
            struct.pack_into(
                "<QQQ",
                page,
                16,
                len(pages) * PAGE,
                struct.unpack_from("<Q", page, 24)[0],
                xml_length,
            )
        data += page + struct.pack(">I", crc32c(page))
    return bytes(data)


def with_xml_edit(path, edit):
    """The file with ``edit(xml)`` as its XML section and valid checksums: a well-formed lie."""
    data = path.read_bytes()
    logical = b"".join(data[i : i + PAGE_DATA] for i in range(0, len(data), PAGE))
    xml_offset, xml_length = struct.unpack_from("<QQ", data, 24)
    start = xml_offset - (xml_offset // PAGE) * 4
    xml = edit(logical[start : start + xml_length])
    return with_valid_checksums(logical[:start] + xml, len(xml))


def replace(old, new):
    return lambda xml: xml.replace(old, new, 1)


def assert_format_error(path, match=None):
    with pytest.raises(FormatError, match=match) as caught:
        pointfield.read(path)
    assert str(path) in str(caught.value)


def test_empty_and_truncated_files_are_format_errors(shared_data, tmp_path):
    data = e57_file(shared_data, "pdal_A4.e57").read_bytes()
    for name, content, match in [
        ("empty.e57", b"", None),
        ("signature.e57", data[:20], "truncated"),
        ("half.e57", data[: len(data) // 2], "header says the file is 4096 bytes"),
    ]:
        (tmp_path / name).write_bytes(content)
        assert_format_error(tmp_path / name, match)


def test_random_bytes_after_the_signature_are_a_format_error(tmp_path):
    rng = np.random.default_rng(0)
    for i in range(10):
        path = tmp_path / f"random{i}.e57"
        path.write_bytes(b"ASTM-E57" + rng.integers(0, 256, 4088, dtype=np.uint8).tobytes())
        assert_format_error(path)


def test_a_flipped_bit_fails_the_page_checksum(shared_data, tmp_path):
    data = bytearray(e57_file(shared_data, "pdal_A_B.e57").read_bytes())
    data[100] ^= 0x10
    path = tmp_path / "flipped.e57"
    path.write_bytes(bytes(data))
    assert_format_error(path, "checksum")


def test_a_huge_record_count_is_refused_before_allocating(shared_data, tmp_path):
    path = tmp_path / "huge.e57"
    path.write_bytes(
        with_xml_edit(
            e57_file(shared_data, "pdal_A4.e57"),
            replace(b'recordCount="4"', b'recordCount="1000000000000"'),
        )
    )
    assert_format_error(path, "scans declare \\[1000000000000\\] records")


def test_a_negative_record_count_is_a_format_error(shared_data, tmp_path):
    path = tmp_path / "negative.e57"
    path.write_bytes(
        with_xml_edit(
            e57_file(shared_data, "pdal_A4.e57"), replace(b'recordCount="4"', b'recordCount="-1"')
        )
    )
    assert_format_error(path)


def test_mutated_files_read_or_raise_format_error(shared_data, tmp_path):
    rng = np.random.default_rng(4)
    sources = [
        e57_file(shared_data, name)
        for name in ("pdal_A4.e57", "pdal_A_B.e57", "pye57_testWithNormals.e57")
    ]
    numbers = [b"0", b"-1", b"4294967296", b"9223372036854775807", b"1e308", b"nan"]

    def change_a_number(xml):
        found = list(re.finditer(rb"-?\d+(\.\d+)?(e[-+]?\d+)?", xml))
        number = found[int(rng.integers(len(found)))]
        return (
            xml[: number.start()] + numbers[int(rng.integers(len(numbers)))] + xml[number.end() :]
        )

    for case in range(90):
        source = sources[case % len(sources)]
        if case % 2:
            data = bytearray(source.read_bytes())
            data[int(rng.integers(len(data)))] ^= 1 << int(rng.integers(8))
        else:  # a number of the XML changed and the checksums made right again
            data = with_xml_edit(source, change_a_number)
        path = tmp_path / f"case{case}.e57"
        path.write_bytes(bytes(data))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                pointfield.read(path)
            except FormatError as error:
                assert str(path) in str(error)
        path.unlink()
