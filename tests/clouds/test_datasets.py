"""Datasets: folder layouts, bad files reported by name, ModelNet's three forms, collation."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

import pointfield
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets import CloudCollate, CloudFolder, ModelNet, modelnet_source
from pointfield.clouds.mesh import Mesh
from pointfield.clouds.shapes import SyntheticShapes
from pointfield.clouds.transforms import RandomJitter
from pointfield.errors import FormatError, PointfieldError


def cloud(count: int = 20, seed: int = 0, **fields) -> PointCloud:
    points = np.random.default_rng(seed).normal(size=(count, 3)).astype(np.float32)
    return PointCloud(points, fields)


def tetrahedron() -> Mesh:
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    return Mesh(points, faces=np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))


@pytest.fixture
def class_folder(tmp_path: Path) -> Path:
    """chair: a PLY, a PCD, an XYZ; table: an NPY and an OFF mesh; plus a README to ignore."""
    (tmp_path / "chair").mkdir()
    (tmp_path / "table").mkdir()
    pointfield.write(tmp_path / "chair" / "a.ply", cloud(seed=1))
    pointfield.write(tmp_path / "chair" / "b.pcd", cloud(seed=2))
    pointfield.write(tmp_path / "chair" / "c.xyz", cloud(seed=3))
    pointfield.write(tmp_path / "table" / "d.npy", cloud(seed=4))
    pointfield.write(tmp_path / "table" / "e.off", tetrahedron())
    (tmp_path / "README.md").write_text("not a cloud")
    return tmp_path


def test_cloud_folder_reads_every_format_with_classes_from_subfolders(class_folder):
    dataset = CloudFolder(class_folder, mesh_points=64)
    assert dataset.classes == ["chair", "table"]
    assert [p.name for p in dataset.files] == ["a.ply", "b.pcd", "c.xyz", "d.npy", "e.off"]
    assert dataset.labels == [0, 0, 0, 1, 1]
    mesh_sample, label = dataset[4]
    assert len(mesh_sample) == 64 and "normals" in mesh_sample.fields and label == 1


def test_without_a_test_split_the_last_fifth_of_each_class_is_held_out(class_folder):
    train = CloudFolder(class_folder, "train")
    test = CloudFolder(class_folder, "test")
    assert test.held_out and [p.name for p in test.files] == ["c.xyz", "e.off"]
    assert [p.name for p in train.files] == ["a.ply", "b.pcd", "d.npy"]


def test_split_folders_above_the_classes(tmp_path):
    for split, count in (("train", 3), ("test", 1)):
        for name in ("bed", "sofa"):
            for i in range(count):
                (tmp_path / split / name).mkdir(parents=True, exist_ok=True)
                pointfield.write(tmp_path / split / name / f"{i}.npy", cloud(seed=i))
    train, test = CloudFolder(tmp_path, "train"), CloudFolder(tmp_path, "test")
    assert (len(train), len(test), train.classes, test.held_out) == (6, 2, ["bed", "sofa"], False)


def test_split_folders_inside_each_class_as_modelnet_has_them(tmp_path):
    for name in ("bed", "sofa"):
        for split, count in (("train", 2), ("test", 1)):
            folder = tmp_path / name / split
            folder.mkdir(parents=True)
            for i in range(count):
                pointfield.write(folder / f"{name}_{i}.npy", cloud(seed=i))
    test = CloudFolder(tmp_path, "test")
    assert [p.name for p in test.files] == ["bed_0.npy", "sofa_0.npy"] and test.labels == [0, 1]


def test_unreadable_files_are_skipped_with_a_warning_naming_them(class_folder):
    (class_folder / "chair" / "broken.ply").write_bytes(b"ply\nformat nonsense\n")
    (class_folder / "chair" / "empty.xyz").write_text("")
    nan_points = np.full((5, 3), np.nan, np.float32)
    pointfield.write(class_folder / "table" / "nan.npy", PointCloud(nan_points))
    with pytest.warns(UserWarning) as caught:
        dataset = CloudFolder(class_folder)
    messages = " ".join(str(w.message) for w in caught)
    for name in ("broken.ply", "empty.xyz", "nan.npy"):
        assert name in messages
    assert {p.name for p, _ in dataset.skipped} == {"broken.ply", "empty.xyz", "nan.npy"}
    assert len(dataset) == 5


def test_unreadable_files_are_fatal_when_asked(class_folder):
    (class_folder / "chair" / "broken.ply").write_bytes(b"ply\nformat nonsense\n")
    with pytest.raises(FormatError, match="broken.ply"):
        CloudFolder(class_folder, on_error="fail")


def test_nan_points_are_dropped_and_nan_normals_zeroed(tmp_path):
    (tmp_path / "a").mkdir()
    points = np.array([[0, 0, 0], [np.nan, 1, 1], [1, 1, 1]], np.float32)
    normals = np.array([[np.nan, 0, 0], [0, 0, 1], [0, 0, 1]], np.float32)
    pointfield.write(tmp_path / "a" / "x.ply", PointCloud(points, {"normals": normals}))
    loaded, _ = CloudFolder(tmp_path)[0]
    assert len(loaded) == 2 and np.isfinite(loaded.fields["normals"]).all()


def test_sampled_meshes_are_cached_and_reused(class_folder, tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    first = CloudFolder(class_folder, cache_dir=cache, mesh_points=32)
    entries = list(cache.rglob("*.npz"))
    assert len(entries) >= 1
    second = CloudFolder(class_folder, cache_dir=cache, mesh_points=32)
    np.testing.assert_array_equal(first.clouds[4].points, second.clouds[4].points)


def test_label_field_becomes_part_labels(tmp_path):
    (tmp_path / "scene").mkdir()
    labels = np.array([0, 2, 1, 2], np.int32)
    pointfield.write(tmp_path / "scene" / "s.ply", cloud(4, class_id=labels))
    dataset = CloudFolder(tmp_path, label_field="class_id")
    assert dataset.parts == ["0", "1", "2"]
    assert dataset[0][0].fields["label"].tolist() == [0, 2, 1, 2]


def test_a_file_without_the_label_field_is_reported(tmp_path):
    (tmp_path / "scene").mkdir()
    pointfield.write(tmp_path / "scene" / "s.ply", cloud(4))
    with pytest.raises(FormatError, match="s.ply.*class_id"):
        CloudFolder(tmp_path, label_field="class_id", on_error="fail")


def test_transform_randomness_is_fixed_per_epoch_and_item():
    dataset = SyntheticShapes("train", 1, points=50, transform=RandomJitter(0.1))
    a, b = dataset[3][0].points, dataset[3][0].points
    dataset.set_epoch(1)
    c = dataset[3][0].points
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_collate_pads_variable_sizes_and_masks_the_padding():
    samples = [
        (cloud(3, label=np.array([1, 2, 3]), normals=np.ones((3, 3), np.float32)), 0),
        (cloud(5, seed=1, label=np.zeros(5, int), normals=np.ones((5, 3), np.float32)), 4),
    ]
    batch = CloudCollate(features=("normals",), point_labels=True)(samples)
    assert batch.points.shape == (2, 5, 3) and batch.features.shape == (2, 5, 3)
    assert batch.mask.tolist() == [[True] * 3 + [False] * 2, [True] * 5]
    assert batch.point_labels[0].tolist() == [1, 2, 3, -1, -1]
    assert batch.labels.tolist() == [0, 4]
    torch.testing.assert_close(batch.points[1], torch.from_numpy(samples[1][0].points))


def test_collate_of_equal_sizes_has_no_mask_and_refuses_empty_clouds():
    assert CloudCollate()([(cloud(4), 0), (cloud(4, 1), 1)]).mask is None
    with pytest.raises(PointfieldError, match="no points"):
        CloudCollate()([(cloud(4), 0), (PointCloud(np.zeros((0, 3), np.float32)), 1)])


def test_modelnet_samples_load_through_modelnet_and_cloud_folder(shared_data, tmp_path):
    root = shared_data / "modelnet" / "ModelNet10"
    assert modelnet_source(root) == "off"
    modelnet = ModelNet(root, "train", cache_dir=tmp_path, points_per_shape=256)
    assert modelnet.classes == ["bathtub", "chair", "toilet"]
    assert modelnet.held_out and len(modelnet) == 4  # no test folders: one per class held out
    test = ModelNet(root, "test", cache_dir=tmp_path, points_per_shape=256)
    assert sorted(p.name for p in test.files) == ["bathtub_0004.off", "chair_0002.off",
                                                  "toilet_0002.off"]
    folder = CloudFolder(root, mesh_points=256, cache_dir=tmp_path)
    assert len(folder) == 7 and all(len(c) == 256 for c in folder.clouds)


def test_modelnet_normal_resampled_text_layout(tmp_path):
    (tmp_path / "modelnet40_shape_names.txt").write_text("airplane\nnight_stand\n")
    (tmp_path / "modelnet40_train.txt").write_text("airplane_0001\nnight_stand_0001\n")
    (tmp_path / "modelnet40_test.txt").write_text("night_stand_0002\n")
    rng = np.random.default_rng(0)
    for shape_id in ("airplane_0001", "night_stand_0001", "night_stand_0002"):
        folder = tmp_path / shape_id.rsplit("_", 1)[0]
        folder.mkdir(exist_ok=True)
        normals = rng.normal(size=(30, 3))
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        rows = np.hstack([rng.normal(size=(30, 3)), normals])
        np.savetxt(folder / f"{shape_id}.txt", rows, fmt="%.6f", delimiter=",")
    train = ModelNet(tmp_path, "train", points_per_shape=20, cache_dir=tmp_path / "cache")
    assert train.source == "txt" and train.labels == [0, 1]
    assert len(train[1][0]) == 20 and "normals" in train[1][0].fields
    assert ModelNet(tmp_path, "test").labels == [1]


def test_modelnet_hdf5_layout(tmp_path):
    h5py = pytest.importorskip("h5py")
    rng = np.random.default_rng(0)
    with h5py.File(tmp_path / "ply_data_train0.h5", "w") as h5:
        h5["data"] = rng.normal(size=(3, 64, 3)).astype(np.float32)
        h5["label"] = np.array([[0], [1], [1]], np.uint8)
        h5["normal"] = rng.normal(size=(3, 64, 3)).astype(np.float32)
    (tmp_path / "shape_names.txt").write_text("airplane\nbathtub\n")
    dataset = ModelNet(tmp_path, "train", points_per_shape=32)
    assert dataset.source == "h5" and dataset.classes == ["airplane", "bathtub"]
    assert dataset.labels == [0, 1, 1] and len(dataset[0][0]) == 32


def test_a_broken_hdf5_file_is_a_format_error(tmp_path):
    pytest.importorskip("h5py")
    (tmp_path / "ply_data_train0.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    with pytest.raises(FormatError, match="ply_data_train0.h5"):
        ModelNet(tmp_path, "train")


def test_a_folder_without_clouds_is_an_error(tmp_path):
    with pytest.raises(PointfieldError, match="no point-cloud"):
        CloudFolder(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert modelnet_source(tmp_path) == "off"
