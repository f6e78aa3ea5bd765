"""Bad datasets raise the project's FormatError naming the file and the frame -- never a traceback.

Covers the issue's list (missing images, inconsistent image sizes, malformed JSON, non-rigid
rotations, NaN in poses, out-of-range COLMAP camera ids) and a small mutation fuzz of each
format's files: every outcome is a Scene or a FormatError.
"""

from __future__ import annotations

import io
import json
import shutil
import struct
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest

from pointfield.errors import FormatError
from pointfield.scenes import Scene, read_scene
from pointfield.scenes.formats.export import write_png

IDENTITY_POSE = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]


def blender_dataset(folder: Path, count: int = 3, size: tuple[int, int] = (8, 6)) -> Path:
    """A minimal Blender dataset: ``count`` frames of ``size`` (w, h) grey PNGs in train/."""
    (folder / "train").mkdir(parents=True)
    frames = []
    for index in range(count):
        write_png(folder / f"train/r_{index}.png", np.full((size[1], size[0], 3), index / 4))
        frames.append({"file_path": f"./train/r_{index}", "transform_matrix": IDENTITY_POSE})
    write_json(folder / "transforms_train.json", {"camera_angle_x": 0.7, "frames": frames})
    return folder


def write_json(path: Path, document) -> None:
    path.write_text(json.dumps(document, indent=1))


def edit_frame(folder: Path, index: int, **changes) -> None:
    path = folder / "transforms_train.json"
    document = json.loads(path.read_text())
    document["frames"][index].update(changes)
    write_json(path, document)


def colmap_text_model(folder: Path, camera_id_of_image: int = 1, quaternion=(1.0, 0.0, 0.0, 0.0)) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cameras.txt").write_text("# cameras\n1 PINHOLE 8 6 10 10 4 3\n")
    q = " ".join(map(str, quaternion))
    (folder / "images.txt").write_text(
        f"# images\n1 {q} 0 0 4 {camera_id_of_image} a.png\n1.0 2.0 1\n2 {q} 1 0 4 1 b.png\n\n"
    )
    (folder / "points3D.txt").write_text("1 0.1 0.2 0.3 255 0 0 0.5 1 0\n")
    return folder


def colmap_binary_model(folder: Path, camera_id_of_image: int = 1) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    cameras = struct.pack("<Q", 1) + struct.pack("<iiQQ", 1, 1, 8, 6) + struct.pack("<4d", 10, 10, 4, 3)
    images = struct.pack("<Q", 2)
    for image_id, name, tx in ((1, b"a.png", 0), (2, b"b.png", 1)):
        images += struct.pack(
            "<i7di", image_id, 1, 0, 0, 0, tx, 0, 4, camera_id_of_image if image_id == 1 else 1
        )
        images += name + b"\x00" + struct.pack("<Q", 1) + struct.pack("<ddq", 1.0, 2.0, 1)
    points = (
        struct.pack("<Q", 1)
        + struct.pack("<Q3d3BdQ", 1, 0.1, 0.2, 0.3, 255, 0, 0, 0.5, 1)
        + struct.pack("<ii", 1, 0)
    )
    (folder / "cameras.bin").write_bytes(cameras)
    (folder / "images.bin").write_bytes(images)
    (folder / "points3D.bin").write_bytes(points)
    return folder


def with_images(folder: Path) -> Path:
    images = folder / "images"
    images.mkdir(exist_ok=True)
    for name in ("a.png", "b.png"):
        write_png(images / name, np.zeros((6, 8, 3)))
    return folder


# -- missing and inconsistent images -------------------------------------------------------------


def test_missing_image_is_an_error_naming_the_file_and_frame_when_asked(tmp_path):
    folder = blender_dataset(tmp_path / "scene")
    (folder / "train/r_1.png").unlink()
    with pytest.raises(
        FormatError, match=r"transforms_train\.json: frame 1 \(\./train/r_1\): image .*r_1\.png not found"
    ):
        read_scene(folder, missing_images="error")


def test_missing_images_are_skipped_with_one_warning_counting_them(tmp_path):
    folder = blender_dataset(tmp_path / "scene", count=4)
    (folder / "train/r_1.png").unlink()
    (folder / "train/r_3.png").unlink()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = read_scene(folder)
    assert [str(w.message).split(": ", 1)[1][:30] for w in caught] == ["2 of 4 frames have no image fi"]
    assert [frame.name for frame in scene.frames] == ["./train/r_0", "./train/r_2"]


def test_dataset_without_any_image_is_an_error(tmp_path):
    folder = blender_dataset(tmp_path / "scene", count=2)
    shutil.rmtree(folder / "train")
    with pytest.raises(FormatError, match=r"no frame has its image; frame 0 \(\./train/r_0\)"):
        read_scene(folder)


def test_image_deleted_after_reading_fails_on_load_naming_the_frame(tmp_path):
    folder = blender_dataset(tmp_path / "scene")
    scene = read_scene(folder)
    (folder / "train/r_2.png").unlink()
    with pytest.raises(FormatError, match=r"r_2\.png: frame 2 \(\./train/r_2\): image file not found"):
        scene.image(2)


def test_blender_images_of_different_sizes_are_an_error(tmp_path):
    folder = blender_dataset(tmp_path / "scene")
    write_png(folder / "train/r_2.png", np.zeros((7, 8, 3)))
    with pytest.raises(
        FormatError, match=r"frame 2 \(\./train/r_2\): image is 8x7 but frame 0 \(\./train/r_0\)'s is 8x6"
    ):
        read_scene(folder)


def test_image_not_matching_declared_size_is_an_error(tmp_path):
    folder = blender_dataset(tmp_path / "scene")
    edit_frame(folder, 1, w=16, h=12)
    with pytest.raises(
        FormatError, match=r"frame 1 \(\./train/r_1\): image r_1\.png is 8x6 but the file declares 16x12"
    ):
        read_scene(folder)


def test_corrupt_image_file_is_an_error_naming_it(tmp_path):
    folder = blender_dataset(tmp_path / "scene")
    (folder / "train/r_1.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 20)
    with pytest.raises(FormatError, match=r"r_1\.png: frame 1 \(\./train/r_1\): not a readable image"):
        read_scene(folder)


def test_truncated_image_data_fails_on_load_not_on_read(tmp_path):
    folder = blender_dataset(tmp_path / "scene")
    write_png(folder / "train/r_1.png", np.random.default_rng(0).random((6, 8, 3)))
    data = (folder / "train/r_1.png").read_bytes()
    (folder / "train/r_1.png").write_bytes(data[: len(data) - 30])
    scene = read_scene(folder)
    with pytest.raises(FormatError, match=r"frame 1 \(\./train/r_1\): cannot decode image"):
        scene.image(1)


# -- malformed transforms files --------------------------------------------------------------------


def test_malformed_json_is_an_error_with_line_and_column(tmp_path):
    folder = blender_dataset(tmp_path / "scene")
    text = (folder / "transforms_train.json").read_text()
    (folder / "transforms_train.json").write_text(text[:40])
    with pytest.raises(FormatError, match=r"transforms_train\.json: malformed JSON at line \d+ column \d+"):
        read_scene(folder)


@pytest.mark.parametrize(
    "matrix, message",
    [
        ([[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 4], [0, 0, 0, 1]], "not rigid"),
        ([[1, 0.5, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]], "not rigid"),
        ([[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]], "reflection"),
        ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 1, 1]], "last row"),
        ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], "4 rows"),
        ([[1, 0, 0, "x"], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]], "expected a number"),
    ],
)
def test_bad_pose_matrices_are_errors_naming_the_frame(tmp_path, matrix, message):
    folder = blender_dataset(tmp_path / "scene")
    edit_frame(folder, 2, transform_matrix=matrix)
    with pytest.raises(FormatError, match=rf"transforms_train\.json: frame 2 \(\./train/r_2\): .*{message}"):
        read_scene(folder)


def test_nan_in_a_pose_is_an_error(tmp_path):
    folder = blender_dataset(tmp_path / "scene")
    text = (folder / "transforms_train.json").read_text()
    document = json.loads(text)
    document["frames"][1]["transform_matrix"][0][3] = float("nan")
    (folder / "transforms_train.json").write_text(json.dumps(document))  # writes the NaN literal
    with pytest.raises(FormatError, match=r"frame 1 \(\./train/r_1\): nan is not a finite number"):
        read_scene(folder)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"frames": "all"}, 'expected a "frames" list'),
        ({"camera_angle_x": -1}, "camera_angle_x: must be positive"),
        ({"camera_angle_x": 4.0}, "not below pi"),
        ({"camera_model": "EQUIRECTANGULAR"}, "not supported"),
        ({"w": 8}, 'only one of "w" and "h"'),
        ({"k4": 0.1}, "k4 is a fisheye coefficient"),
    ],
)
def test_bad_top_level_values_are_errors(tmp_path, change, message):
    folder = blender_dataset(tmp_path / "scene")
    document = json.loads((folder / "transforms_train.json").read_text())
    document.update(change)
    write_json(folder / "transforms_train.json", document)
    with pytest.raises(FormatError, match=message):
        read_scene(folder)


def test_frame_without_file_path_is_an_error(tmp_path):
    folder = blender_dataset(tmp_path / "scene")
    document = json.loads((folder / "transforms_train.json").read_text())
    del document["frames"][0]["file_path"]
    write_json(folder / "transforms_train.json", document)
    with pytest.raises(FormatError, match=r'frame 0: missing or empty "file_path"'):
        read_scene(folder)


def test_split_list_naming_no_frame_is_an_error(tmp_path):
    folder = tmp_path / "scene"
    blender_dataset(folder)
    document = json.loads((folder / "transforms_train.json").read_text())
    document["test_filenames"] = ["train/r_9.png"]
    write_json(folder / "transforms.json", document)
    with pytest.raises(FormatError, match="test_filenames lists 'train/r_9.png'"):
        read_scene(folder / "transforms.json")


def test_folder_with_no_scene_is_an_error(tmp_path):
    with pytest.raises(FormatError, match="no scene found"):
        read_scene(tmp_path)


# -- COLMAP --------------------------------------------------------------------------------------


def test_colmap_text_and_binary_minimal_models_read_the_same(tmp_path):
    text = read_scene(with_images(colmap_text_model(tmp_path / "text")))
    binary = read_scene(with_images(colmap_binary_model(tmp_path / "binary")))
    assert isinstance(text, Scene) and len(text) == len(binary) == 2
    assert np.array_equal(text.cameras.camera_to_world.numpy(), binary.cameras.camera_to_world.numpy())
    assert np.array_equal(text.points.points, binary.points.points)


@pytest.mark.parametrize("make", [colmap_text_model, colmap_binary_model])
def test_colmap_image_with_an_out_of_range_camera_id_is_an_error(tmp_path, make):
    folder = with_images(make(tmp_path / "model", camera_id_of_image=7))
    with pytest.raises(
        FormatError, match=r"images\.(txt|bin): image 1 \(a\.png\): camera id 7 is not in cameras\.(txt|bin)"
    ):
        read_scene(folder)


def test_colmap_non_unit_quaternion_is_an_error(tmp_path):
    folder = with_images(colmap_text_model(tmp_path / "model", quaternion=(2.0, 0.0, 0.0, 0.0)))
    with pytest.raises(FormatError, match=r"image 1 \(a\.png\): quaternion has norm 2, not 1"):
        read_scene(folder)


def test_colmap_nan_pose_is_an_error(tmp_path):
    folder = with_images(colmap_text_model(tmp_path / "model", quaternion=("nan", 0.0, 0.0, 0.0)))
    with pytest.raises(FormatError, match=r"image 1 \(a\.png\): pose contains NaN"):
        read_scene(folder)


def test_colmap_unsupported_camera_model_is_an_error(tmp_path):
    folder = with_images(colmap_text_model(tmp_path / "model"))
    (folder / "cameras.txt").write_text("1 FOV 8 6 10 10 4 3 0.1\n")
    with pytest.raises(FormatError, match="model FOV is not supported"):
        read_scene(folder)


def test_colmap_binary_count_larger_than_the_file_is_refused_before_allocating(tmp_path):
    folder = with_images(colmap_binary_model(tmp_path / "model"))
    data = bytearray((folder / "points3D.bin").read_bytes())
    data[:8] = struct.pack("<Q", 10**15)
    (folder / "points3D.bin").write_bytes(bytes(data))
    with pytest.raises(FormatError, match=r"points3D\.bin: declares 1000000000000000 points"):
        read_scene(folder)


def test_colmap_truncated_binary_is_an_error(tmp_path):
    folder = with_images(colmap_binary_model(tmp_path / "model"))
    data = (folder / "images.bin").read_bytes()
    (folder / "images.bin").write_bytes(data[:-5])
    with pytest.raises(FormatError, match=r"images\.bin: .*(truncated|declares)"):
        read_scene(folder)


def test_colmap_text_with_a_bad_number_names_the_line(tmp_path):
    folder = with_images(colmap_text_model(tmp_path / "model"))
    (folder / "cameras.txt").write_text("# c\n1 PINHOLE 8 six 10 10 4 3\n")
    with pytest.raises(FormatError, match=r"cameras\.txt: line 2: height 'six' is not a valid int"):
        read_scene(folder)


# -- LLFF and npz ----------------------------------------------------------------------------------


def llff_dataset(folder: Path, rows: np.ndarray, images: int) -> Path:
    (folder / "images").mkdir(parents=True)
    for index in range(images):
        write_png(folder / f"images/{index}.png", np.zeros((6, 8, 3)))
    np.save(folder / "poses_bounds.npy", rows)
    return folder


def llff_rows(count: int) -> np.ndarray:
    matrix = np.array([[0.0, 1.0, 0.0, 0.0, 6.0], [1.0, 0.0, 0.0, 0.0, 8.0], [0.0, 0.0, -1.0, 0.0, 10.0]])
    return np.tile(np.concatenate([matrix.ravel(), [1.0, 5.0]]), (count, 1))


def test_llff_row_and_image_counts_must_match(tmp_path):
    with pytest.raises(FormatError, match=r"poses_bounds\.npy: has 3 rows but .*images holds 2 images"):
        read_scene(llff_dataset(tmp_path / "scene", llff_rows(3), 2))


def test_llff_nan_and_non_rigid_rows_are_errors(tmp_path):
    rows = llff_rows(2)
    rows[1, 3] = np.nan
    with pytest.raises(FormatError, match=r"frame 1 \(row 1\): contains NaN"):
        read_scene(llff_dataset(tmp_path / "a", rows, 2))
    rows = llff_rows(2)
    rows[0, 0] = 3.0
    with pytest.raises(FormatError, match=r"frame 0 \(row 0\): pose rotation is not rigid"):
        read_scene(llff_dataset(tmp_path / "b", rows, 2))


def test_llff_wrong_shape_and_hostile_header_are_errors(tmp_path):
    with pytest.raises(FormatError, match=r"expected an \(N, 17\) float array"):
        read_scene(llff_dataset(tmp_path / "a", np.zeros((2, 12)), 2))
    folder = llff_dataset(tmp_path / "b", llff_rows(2), 2)
    data = (folder / "poses_bounds.npy").read_bytes().replace(b"(2, 17)", b"(9999999999, 17)".ljust(7)[:7], 1)
    header = b"{'descr': '<f8', 'fortran_order': False, 'shape': (99999999999, 17), }"
    (folder / "poses_bounds.npy").write_bytes(
        b"\x93NUMPY\x01\x00" + struct.pack("<H", 118) + header.ljust(117) + b"\n" + data[128:]
    )
    with pytest.raises(FormatError, match=r"shape \(99999999999, 17\)\) declares .* bytes but only 272 follow"):
        read_scene(folder)


def tiny_nerf_npz(path: Path, **arrays) -> Path:
    base = {
        "images": np.zeros((2, 6, 8, 3), np.float32),
        "poses": np.stack([np.array(IDENTITY_POSE, np.float32)] * 2),
        "focal": np.array(10.0),
    }
    base.update(arrays)
    np.savez(path, **base)
    return path


def test_npz_reads_images_poses_and_focal(tmp_path):
    scene = read_scene(tiny_nerf_npz(tmp_path / "tiny.npz"), holdout_every=2)
    assert scene.metadata["format"] == "npz" and len(scene) == 2
    assert scene.cameras.fx.tolist() == [10.0, 10.0] and scene.cameras.cx[0].item() == 4.0
    # OpenGL identity looking down -z becomes OpenCV with y and z flipped.
    assert scene.cameras.rotations[0].diagonal().tolist() == [1.0, -1.0, -1.0]
    assert scene.image(1).shape == (6, 8, 3)
    assert scene.splits["test"].tolist() == [0]


@pytest.mark.parametrize(
    "arrays, message",
    [
        ({"focal": np.array(-1.0)}, "focal must be one positive number"),
        ({"poses": np.zeros((3, 4, 4), np.float32)}, r"poses must be \(2, 4, 4\)"),
        ({"images": np.zeros((2, 6, 8), np.float32)}, "images must be"),
        ({"poses": np.stack([np.array(IDENTITY_POSE, np.float32) * 2] * 2)}, "frame 0"),
    ],
)
def test_npz_with_bad_arrays_is_an_error(tmp_path, arrays, message):
    with pytest.raises(FormatError, match=message):
        read_scene(tiny_nerf_npz(tmp_path / "tiny.npz", **arrays))


def test_npz_that_is_not_a_zip_or_lacks_arrays_is_an_error(tmp_path):
    (tmp_path / "junk.npz").write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(FormatError, match="not a readable .npz"):
        read_scene(tmp_path / "junk.npz")
    np.savez(tmp_path / "other.npz", points=np.zeros(3))
    with pytest.raises(FormatError, match="no 'images' array"):
        read_scene(tmp_path / "other.npz")


def test_npz_member_claiming_more_than_its_bytes_is_refused(tmp_path):
    buffer = io.BytesIO()
    np.save(buffer, np.zeros((2, 6, 8, 3), np.float32))
    header_end = buffer.getvalue().index(b"\n") + 1
    header = buffer.getvalue()[:header_end].replace(b"(2, 6, 8, 3)", b"(9, 6, 8, 3)")
    with zipfile.ZipFile(tmp_path / "bad.npz", "w") as archive:
        archive.writestr("images.npy", header + buffer.getvalue()[header_end:])
        for name, array in (("poses", np.zeros((9, 4, 4))), ("focal", np.array(1.0))):
            member = io.BytesIO()
            np.save(member, array)
            archive.writestr(f"{name}.npy", member.getvalue())
    with pytest.raises(FormatError, match=r"images\.npy: the header \(a float32 array of shape \(9, 6, 8, 3\)\) declares .* but only 1152 follow"):
        read_scene(tmp_path / "bad.npz")


# -- mutation fuzz -------------------------------------------------------------------------------------


def mutations(data: bytes, count: int, seed: int):
    """Bit flips, truncations, inserted and deleted bytes, and digit changes (for text formats)."""
    rng = np.random.default_rng(seed)
    for _ in range(count):
        buffer = bytearray(data)
        kind = rng.integers(5)
        position = int(rng.integers(len(buffer)))
        if kind == 0:
            buffer[position] ^= 1 << int(rng.integers(8))
        elif kind == 1:
            del buffer[position:]
        elif kind == 2:
            buffer[position:position] = bytes(rng.integers(0, 256, int(rng.integers(1, 8)), dtype=np.uint8))
        elif kind == 3:
            del buffer[position : position + int(rng.integers(1, 8))]
        else:
            digits = [i for i, b in enumerate(buffer) if chr(b).isdigit()]
            if digits:
                buffer[digits[int(rng.integers(len(digits)))]] = ord(str(int(rng.integers(10))))
        yield bytes(buffer)


@pytest.mark.parametrize(
    "build, victim",
    [
        (lambda folder: blender_dataset(folder), "transforms_train.json"),
        (lambda folder: with_images(colmap_text_model(folder)), "images.txt"),
        (lambda folder: with_images(colmap_text_model(folder)), "cameras.txt"),
        (lambda folder: with_images(colmap_binary_model(folder)), "images.bin"),
        (lambda folder: with_images(colmap_binary_model(folder)), "points3D.bin"),
        (lambda folder: llff_dataset(folder, llff_rows(2), 2), "poses_bounds.npy"),
    ],
)
def test_mutated_files_read_as_a_scene_or_raise_format_error(tmp_path, build, victim):
    folder = build(tmp_path / "scene")
    original = (folder / victim).read_bytes()
    for mutated in mutations(original, 60, seed=len(victim)):
        (folder / victim).write_bytes(mutated)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                scene = read_scene(folder)
            except FormatError:
                continue
        assert isinstance(scene, Scene)
