"""Dataset readers in each dataset's own on-disk layout, built in miniature in tmp_path.

Each fixture writes the exact file names, columns and encodings of the public download; a
missing or malformed file is one PointfieldError naming it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import pointfield
from pointfield.clouds.cloud import PointCloud
from pointfield.clouds.datasets.labelled import ASPRS_CLASSES, LabelledClouds
from pointfield.clouds.datasets.s3dis import S3DIS, S3DIS_CLASSES
from pointfield.clouds.datasets.scannet import BENCHMARK_IDS, ScanNet
from pointfield.clouds.datasets.scenes import open_scenes, scene_layout
from pointfield.clouds.datasets.semantickitti import SemanticKITTI
from pointfield.clouds.datasets.shapenetpart import PART_NAMES, ShapeNetPart
from pointfield.errors import FormatError, PointfieldError

RNG = np.random.default_rng(0)


# ---------------------------------------------------------------------------------------------
# S3DIS: Area_N/<room>/Annotations/<class>_<k>.txt, rows "x y z r g b"
# ---------------------------------------------------------------------------------------------


def write_s3dis_object(path: Path, count: int, z: float) -> None:
    rows = np.column_stack([RNG.uniform(0, 3, (count, 2)), np.full(count, z), RNG.integers(0, 256, (count, 3))])
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, rows, fmt=["%.6f"] * 3 + ["%d"] * 3)


@pytest.fixture
def s3dis(tmp_path) -> Path:
    root = tmp_path / "Stanford3dDataset_v1.2_Aligned_Version"
    for area, rooms in ((1, ("office_1", "hallway_2")), (5, ("office_19",))):
        for room in rooms:
            folder = root / f"Area_{area}" / room
            write_s3dis_object(folder / "Annotations" / "floor_1.txt", 30, 0.0)
            write_s3dis_object(folder / "Annotations" / "chair_1.txt", 10, 0.5)
            write_s3dis_object(folder / "Annotations" / "chair_2.txt", 10, 0.5)
            write_s3dis_object(folder / "Annotations" / "stairs_1.txt", 5, 1.0)
            (folder / f"{room}.txt").write_text("whole room: not read\n")
    (root / "Area_1" / ".DS_Store").write_text("")
    return root


def test_s3dis_holds_out_area_5_and_labels_each_annotation_by_its_name(s3dis):
    train, test = S3DIS(s3dis, "train"), S3DIS(s3dis, "test")
    assert train.names == ["Area_1/hallway_2", "Area_1/office_1"] and test.names == ["Area_5/office_19"]
    assert train.classes == list(S3DIS_CLASSES) and len(train.classes) == 13
    room = test.read(0)
    counts = np.bincount(room.fields["label"], minlength=13)
    assert counts[S3DIS_CLASSES.index("floor")] == 30 and counts[S3DIS_CLASSES.index("chair")] == 20
    assert counts[S3DIS_CLASSES.index("clutter")] == 5  # stairs count as clutter
    assert room.fields["colors"].dtype == np.uint8 and len(room) == 55
    assert np.allclose(room.points[room.fields["label"] == S3DIS_CLASSES.index("floor"), 2], 0.0)


def test_s3dis_names_the_file_and_line_of_a_malformed_row(s3dis):
    bad = s3dis / "Area_5" / "office_19" / "Annotations" / "ceiling_1.txt"
    bad.write_text("1.0 2.0 3.0 10 20 30\n1.0 2.0 \x10 10 20 30\n")
    with pytest.raises(FormatError, match=r"ceiling_1\.txt: line 2"):
        S3DIS(s3dis, "test").read(0)


def test_s3dis_without_its_test_area_says_so(s3dis):
    with pytest.raises(PointfieldError, match="no Area_3 folder"):
        S3DIS(s3dis, "train", test_area=3)


# ---------------------------------------------------------------------------------------------
# ScanNet v2: scans/sceneXXXX_XX/sceneXXXX_XX_vh_clean_2.ply + .labels.ply, and the label table
# ---------------------------------------------------------------------------------------------

TSV_HEADER = ("id\traw_category\tcategory\tcount\tnyu40id\teigen13id\tnyuClass\tnyu40class\teigen13class\t"
              "ModelNet40\tModelNet10\tShapeNetCore55\tsynsetoffset\twnsynsetid\twnsynsetkey\tmpcat40\tmpcat40index")
NYU40 = ["wall", "floor", "cabinet", "bed", "chair", "sofa", "table", "door", "window", "bookshelf", "picture",
         "counter", "blinds", "desk", "shelves", "curtain", "dresser", "pillow", "mirror", "floor mat", "clothes",
         "ceiling", "books", "refridgerator", "television", "paper", "towel", "shower curtain", "box",
         "whiteboard", "person", "night stand", "toilet", "sink", "lamp", "bathtub", "bag", "otherstructure",
         "otherfurniture", "otherprop"]


def write_scannet_scene(scans: Path, name: str, nyu40_ids: np.ndarray) -> None:
    folder = scans / name
    folder.mkdir(parents=True)
    n = len(nyu40_ids)
    points = RNG.uniform(0, 4, (n, 3)).astype(np.float32)
    faces = np.array([[0, 1, 2], [1, 2, 3]])
    colours = np.column_stack([RNG.integers(0, 256, (n, 3)), np.full(n, 255)]).astype(np.uint8)
    pointfield.write(folder / f"{name}_vh_clean_2.ply",
                     pointfield.Mesh(points, {"colors": colours}, faces=faces), encoding="binary")
    pointfield.write(folder / f"{name}_vh_clean_2.labels.ply",
                     pointfield.Mesh(points, {"label": nyu40_ids.astype(np.uint16)}, faces=faces), encoding="binary")


@pytest.fixture
def scannet(tmp_path) -> Path:
    root = tmp_path / "ScanNet"
    rows = [TSV_HEADER] + [f"{i}\traw{i}\tcat{i}\t1\t{i}\t0\tx\t{name}\tx\t\t\t\t\t\t\t\t" for i, name in
                           enumerate(NYU40, start=1)]
    root.mkdir()
    (root / "scannetv2-labels.combined.tsv").write_text("\n".join(rows) + "\n")
    for name in ("scene0000_00", "scene0001_00", "scene0011_00"):
        write_scannet_scene(root / "scans", name, np.array([1, 2, 5, 13, 40, 0, 39, 5]))
    (root / "scannetv2_train.txt").write_text("scene0000_00\nscene0001_00\n")
    (root / "scannetv2_val.txt").write_text("scene0011_00\n")
    return root


def test_scannet_maps_nyu40_ids_to_the_20_benchmark_classes(scannet):
    train, test = ScanNet(scannet, "train"), ScanNet(scannet, "test")
    assert train.names == ["scene0000_00", "scene0001_00"] and test.names == ["scene0011_00"]
    assert len(train.classes) == 20 and train.classes[:3] == ["wall", "floor", "cabinet"]
    assert train.classes[-1] == "otherfurniture"
    scene = test.read(0)
    chair = train.classes.index("chair")
    # wall, floor, chair, blinds (not in the benchmark), otherprop (not), unannotated, otherfurniture, chair
    assert scene.fields["label"].tolist() == [0, 1, chair, -1, -1, -1, 19, chair]
    assert scene.fields["colors"].shape == (8, 3) and scene.fields["colors"].dtype == np.uint8
    assert BENCHMARK_IDS.index(5) == chair


def test_scannet_without_its_label_table_names_the_file(scannet):
    (scannet / "scannetv2-labels.combined.tsv").unlink()
    with pytest.raises(PointfieldError, match="not a ScanNet folder|scannetv2-labels.combined.tsv"):
        ScanNet(scannet, "train")


def test_scannet_with_a_label_file_of_other_vertices_names_it(scannet):
    write_scannet_scene(scannet / "scans", "scene0099_00", np.array([1, 2, 3, 4]))
    labels = scannet / "scans" / "scene0099_00" / "scene0099_00_vh_clean_2.labels.ply"
    pointfield.write(labels, pointfield.Mesh(np.zeros((3, 3), np.float32), {"label": np.ones(3, np.uint16)},
                                             faces=np.array([[0, 1, 2]])), encoding="binary")
    (scannet / "scannetv2_val.txt").write_text("scene0099_00\n")
    with pytest.raises(FormatError, match=r"scene0099_00_vh_clean_2\.labels\.ply: 3 vertices"):
        ScanNet(scannet, "test").read(0)


# ---------------------------------------------------------------------------------------------
# SemanticKITTI: sequences/NN/velodyne/*.bin + labels/*.label, learning_map from semantic-kitti.yaml
# ---------------------------------------------------------------------------------------------


def write_sweep(sequence: Path, name: str, raw_labels: list[int], instances: int = 7) -> None:
    n = len(raw_labels)
    (sequence / "velodyne").mkdir(parents=True, exist_ok=True)
    (sequence / "labels").mkdir(parents=True, exist_ok=True)
    RNG.uniform(-20, 20, (n, 4)).astype("<f4").tofile(sequence / "velodyne" / f"{name}.bin")
    values = (np.uint32(instances) << np.uint32(16)) | np.asarray(raw_labels, np.uint32)
    values.astype("<u4").tofile(sequence / "labels" / f"{name}.label")


@pytest.fixture
def kitti(tmp_path) -> Path:
    root = tmp_path / "dataset"
    write_sweep(root / "sequences" / "00", "000000", [10, 40, 252, 0, 1, 50, 81, 99])
    write_sweep(root / "sequences" / "08", "000000", [10, 70, 72])
    (root / "sequences" / "11" / "velodyne").mkdir(parents=True)  # a test sequence: no labels
    RNG.uniform(-20, 20, (5, 4)).astype("<f4").tofile(root / "sequences" / "11" / "velodyne" / "000000.bin")
    return root


def test_semantickitti_keeps_the_lower_16_bits_and_applies_the_learning_map(kitti):
    train, test = SemanticKITTI(kitti, "train"), SemanticKITTI(kitti, "test")
    assert train.names == ["00/000000"] and test.names == ["08/000000"]
    assert len(train.classes) == 19 and train.classes[0] == "car" and train.classes[-1] == "traffic-sign"
    sweep = train.read(0)
    names = [train.classes[i] if i >= 0 else None for i in sweep.fields["label"]]
    # car, road, moving-car -> car, unlabeled, outlier, building, traffic-sign, other-object -> ignored
    assert names == ["car", "road", "car", None, None, "building", "traffic-sign", None]
    assert sweep.fields["intensity"].dtype == np.float32


def test_semantickitti_reads_the_map_and_splits_from_its_yaml(kitti):
    (kitti / "semantic-kitti.yaml").write_text(
        "labels:\n  0: unlabeled\n  10: car\n  40: road\n"
        "learning_map:\n  0: 0\n  10: 2\n  40: 1\n"
        "learning_map_inv:\n  0: 0\n  1: 40\n  2: 10\n"
        "split:\n  train: [8]\n  valid: [0]\n"
    )
    train = SemanticKITTI(kitti, "train")
    assert train.classes == ["road", "car"] and train.names == ["08/000000"]
    assert train.read(0).fields["label"].tolist() == [1, -1, -1]


def test_semantickitti_names_a_label_file_of_the_wrong_size(kitti):
    (kitti / "sequences" / "00" / "labels" / "000000.label").write_bytes(b"\0" * 12)
    with pytest.raises(FormatError, match=r"000000\.label: 12 bytes, expected 4 per point"):
        SemanticKITTI(kitti, "train").read(0)


# ---------------------------------------------------------------------------------------------
# ShapeNetPart: shapenetcore_partanno_segmentation_benchmark_v0_normal
# ---------------------------------------------------------------------------------------------


@pytest.fixture
def shapenetpart(tmp_path) -> Path:
    root = tmp_path / "shapenetcore_partanno_segmentation_benchmark_v0_normal"
    (root / "train_test_split").mkdir(parents=True)
    (root / "synsetoffset2category.txt").write_text("Airplane\t02691156\nMug\t03797390\n")
    shapes = {"train": [("02691156", "a1"), ("03797390", "m1")], "val": [("02691156", "a2")],
              "test": [("03797390", "m2")]}
    for split, entries in shapes.items():
        listed = [f"shape_data/{synset}/{shape}" for synset, shape in entries]
        (root / "train_test_split" / f"shuffled_{split}_file_list.json").write_text(json.dumps(listed))
        for synset, shape in entries:
            parts = (0, 3) if synset == "02691156" else (36, 37)
            rows = np.column_stack([RNG.normal(size=(20, 3)), np.tile([0, 0, 1.0], (20, 1)),
                                    np.repeat(parts, 10)])
            (root / synset).mkdir(exist_ok=True)
            np.savetxt(root / synset / f"{shape}.txt", rows, fmt="%.6f")
    return root


def test_shapenetpart_trains_on_train_and_val_with_50_global_parts(shapenetpart):
    train, test = ShapeNetPart(shapenetpart, "train"), ShapeNetPart(shapenetpart, "test")
    assert train.classes == ["Airplane", "Mug"] and len(train) == 3 and len(test) == 1
    assert len(train.parts) == 50 and PART_NAMES[36] == "Mug 0"
    assert train.category_parts == [(0, 1, 2, 3), (36, 37)]  # what each shape is scored on
    cloud, label = test[0]
    assert label == 1 and sorted(set(cloud.fields["label"].tolist())) == [36, 37]
    assert cloud.fields["normals"].shape == (20, 3)


def test_shapenetpart_names_a_listed_shape_whose_file_is_missing(shapenetpart):
    (shapenetpart / "03797390" / "m2.txt").unlink()
    with pytest.raises(FormatError, match=r"m2\.txt: missing"):
        ShapeNetPart(shapenetpart, "test", on_error="fail")
    with pytest.warns(UserWarning, match=r"m2\.txt: skipped"):
        assert len(ShapeNetPart(shapenetpart, "test")) == 0


def test_shapenetpart_refuses_a_part_outside_its_category(shapenetpart):
    path = shapenetpart / "03797390" / "m2.txt"
    path.write_text("0 0 0 0 0 1 5.000000\n")
    with pytest.raises(FormatError, match=r"m2\.txt: part label 5 is not one of Mug's parts"):
        ShapeNetPart(shapenetpart, "test", on_error="fail")


# ---------------------------------------------------------------------------------------------
# Labelled clouds in any format, with a class table given once
# ---------------------------------------------------------------------------------------------


def labelled_cloud(labels: list[int], field: str = "label") -> PointCloud:
    n = len(labels)
    points = np.column_stack([np.arange(n, dtype=np.float64), np.zeros((n, 2))])
    return PointCloud(points, {field: np.asarray(labels, np.uint8 if field == "classification" else np.int32)})


def test_a_folder_of_labelled_plys_with_a_classes_json_gives_named_classes(tmp_path):
    for split, name in (("train", "a"), ("train", "b"), ("test", "c")):
        (tmp_path / split).mkdir(exist_ok=True)
        pointfield.write(tmp_path / split / f"{name}.ply", labelled_cloud([0, 1, 2, 1, 7]))
    (tmp_path / "classes.json").write_text('["floor", "wall", "chair"]')
    train, test = open_scenes([tmp_path], "train"), open_scenes([tmp_path], "test")
    assert scene_layout([tmp_path]) == "labelled"
    assert train.classes == ["floor", "wall", "chair"] and train.names == ["a", "b"] and test.names == ["c"]
    assert test.read(0).fields["label"].tolist() == [0, 1, 2, 1, -1]  # 7 is outside the table


def test_a_las_classification_gets_the_asprs_names_of_the_codes_present(tmp_path):
    path = tmp_path / "tile.las"
    pointfield.write(path, labelled_cloud([2, 2, 6, 1, 2, 6, 2, 1, 2, 2], "classification"))
    train = LabelledClouds([path], "train")
    assert train.codes == [1, 2, 6] and train.classes == [ASPRS_CLASSES[1], "ground", "building"]
    # One file: its last fifth along x is the test split.
    train_part, test_part = train.read(0), LabelledClouds([path], "test").read(0)
    assert len(train_part) + len(test_part) == 10 and test_part.points[:, 0].min() > train_part.points[:, 0].max()


def test_a_file_without_the_label_field_is_named(tmp_path):
    path = tmp_path / "plain.ply"
    pointfield.write(path, PointCloud(np.zeros((3, 3), np.float32)))
    with pytest.raises(FormatError, match=r"plain\.ply: has no per-point 'classification' or 'label' field"):
        LabelledClouds([path], "train")


def test_a_malformed_class_table_is_named(tmp_path):
    pointfield.write(tmp_path / "a.ply", labelled_cloud([0, 1]))
    (tmp_path / "classes.json").write_text('{"zero": 1}')
    with pytest.raises(FormatError, match=r"classes\.json: expected a list of class names"):
        LabelledClouds([tmp_path / "a.ply"], "train")


def test_segment_train_on_shapenetpart_learns_its_50_parts(shapenetpart, tmp_path):
    metrics = pointfield.segment.train(shapenetpart, out=tmp_path / "run", epochs=1, points=16, batch_size=2,
                                       device="cpu", progress=False, normals=True)
    assert len(metrics["per_class"]) == 50 and "Mug 1" in metrics["per_class"]
    # ShapeNetPart's own scores beside the part IoUs: the one test shape is a mug, so the airplane has none.
    assert metrics["per_category"]["Airplane"] is None
    assert metrics["class_miou"] == metrics["instance_miou"] == metrics["per_category"]["Mug"]
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["instance_miou"] == metrics["instance_miou"]
