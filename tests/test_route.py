"""`pointfield route`: what each input is (from headers only), which representation a task needs,
the commands to run (real ones: each parses), and the errors, through Python and the CLI."""

from __future__ import annotations

import json
import shlex
import shutil

import numpy as np
import pytest

import pointfield
from pointfield.cli import build_parser, main
from pointfield.errors import PointfieldError
from pointfield.route import SCHEMA, format_route, inspect_path, parse_task, route
from pointfield.route import inputs as route_inputs
from pointfield.volumes import read_voxels

# -- fixtures ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def nerf_run(tmp_path_factory):
    """TinyNeRF, one step on three 8-pixel views of the cube: a real, finished run folder."""
    from pointfield.fields.train import train

    out = tmp_path_factory.mktemp("runs") / "cube-tiny"
    train(None, model="tiny", out=out, steps=1, eval_every=1, batch_rays=64, cube_views=3, cube_size=8,
          device="cpu", model_options={"samples": 4}, progress=False)
    return out


@pytest.fixture(scope="module")
def classify_run(tmp_path_factory):
    """PointNet without T-Nets, one epoch on two synthetic shapes per class."""
    out = tmp_path_factory.mktemp("runs") / "shapes"
    pointfield.classify.train(out=out, epochs=1, points=32, shapes_per_class=2, batch_size=8, device="cpu",
                              input_transform=False, feature_transform=False, progress=False)
    return out


@pytest.fixture()
def photo_folder(shared_data, tmp_path):
    """Three of the fox's photos copied into a folder of their own: photos without poses."""
    folder = tmp_path / "my photos"
    folder.mkdir()
    for name in ("0001.jpg", "0002.jpg", "0003.jpg"):
        shutil.copy(shared_data / "nerf/fox_instant_ngp/images" / name, folder / name)
    return folder


@pytest.fixture()
def video(tmp_path):
    """A 32 x 48 clip of 10 frames at 5 fps."""
    pytest.importorskip("imageio_ffmpeg", reason="imageio-ffmpeg (the video extra) is not installed")
    import imageio.v2 as imageio

    path = tmp_path / "walk.mp4"
    frames = [np.full((32, 48, 3), 20 * i, np.uint8) for i in range(10)]
    imageio.mimwrite(path, frames, fps=5, macro_block_size=16)
    return path


def _cli(capsys, *argv) -> tuple[int, str, str]:
    code = main(["route", *map(str, argv)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# -- what each input is --------------------------------------------------------------------------


@pytest.mark.parametrize(("name", "kind", "expected"), [
    ("pcd/pcl_table_scene_mug_organized.pcd", "cloud",
     {"format": "pcd", "encoding": "binary_compressed", "points": 307200, "organised": [480, 640], "read": "header"}),
    ("ply/armadillo_points_normals_ascii.ply", "cloud", {"format": "ply", "points": 38294, "faces": 0}),
    ("ply/trimesh_bunny_ascii_mesh.ply", "mesh", {"format": "ply", "points": 8171, "faces": 16301}),
    ("gaussians/3dgs_point_cloud_iter7000.ply", "splats", {"points": 9080, "sh_degree": 3, "read": "header"}),
    ("las/autzen_trim.laz", "cloud", {"format": "las", "encoding": "laz", "points": 110000, "read": "header"}),
    ("las/test1_4.las", "cloud", {"encoding": "las", "points": 1000, "version": "1.4", "point_format": 6}),
    ("e57/pye57_pumpAVisualReferenceImage.e57", "cloud", {"points": 155201, "organised": "rows and columns"}),
    ("e57/pdal_A_B.e57", "cloud", {"points": 6, "scans": 2}),
    ("xyz_pts/trimesh_points_agisoft.xyz", "cloud", {"format": "text", "points": 100, "read": "whole file"}),
    ("xyz_pts/pdal_autzen.pts", "cloud", {"format": "text", "points": 10}),
    ("kitti/semantickitti_seq00/000000.bin", "cloud", {"format": "velodyne", "points": 124668, "read": "size"}),
    ("modelnet/ModelNet10/chair/train/chair_0001.off", "mesh", {"format": "off", "points": 2382, "faces": 2234}),
])
def test_a_file_is_recognised_with_its_size_and_fields(shared_data, name, kind, expected):
    given = inspect_path(shared_data / name)
    assert given.kind == kind
    assert {key: given.details[key] for key in expected} == expected


def test_a_splat_ply_is_told_apart_from_a_cloud_ply_by_its_properties(shared_data):
    splats = inspect_path(shared_data / "gaussians/3dgs_point_cloud_iter7000.ply")
    cloud = inspect_path(shared_data / "ply/pcu_duplicated_pcloud_double_normals.ply")
    assert (splats.kind, cloud.kind) == ("splats", "cloud")
    assert {"opacity", "scale_0", "rot_3", "f_dc_0"} <= set(splats.details["fields"])


def test_the_laz_header_gives_bounds_and_dimensions(shared_data):
    details = inspect_path(shared_data / "las/simple.las").details
    assert details["bounds"]["min"][0] == pytest.approx(635619.85, abs=0.01)
    assert "classification" in details["fields"]


def test_an_npz_is_described_from_its_headers_with_the_points_the_reader_takes(tmp_path):
    path = tmp_path / "two.npz"
    np.savez(path, pos=np.zeros((5, 3)), points=np.ones((7, 3)), label=np.arange(7))  # "points" comes first
    details = inspect_path(path).details
    with pytest.warns(UserWarning, match="'pos'"):  # not one value per point of "points"
        assert details["points"] == len(pointfield.read(path)) == 7
    assert details["read"] == "header" and details["fields"] == ["pos", "label"]


@pytest.mark.parametrize(("name", "scene_format", "frames", "listed", "obj"), [
    ("nerf/lego_blender", "blender", 100, 100, True),
    ("nerf/fox_instant_ngp", "nerfstudio", 50, 67, False),
    ("llff/milk", "llff", 43, 43, False),
    ("colmap/tiny_phone_scene/sparse/0", "colmap", 3, 3, False),
    ("colmap/tiny_phone_scene/text", "colmap", 3, 3, False),
])
def test_a_posed_dataset_is_recognised_with_its_format(shared_data, name, scene_format, frames, listed, obj):
    given = inspect_path(shared_data / name)
    assert given.kind == "scene"
    details = given.details
    assert (details["format"], details["frames"], details["frames_listed"], details["object"]) == (
        scene_format, frames, listed, obj)


def test_a_scene_file_is_named_after_its_folder(shared_data):
    answer = route(shared_data / "nerf/fox_instant_ngp/transforms.json")
    assert answer.input.kind == "scene" and answer.input.details["frames"] == 50
    assert answer.commands[0].endswith("--out runs/fox_instant_ngp")


def test_the_colmap_model_brings_its_sparse_points(shared_data):
    assert inspect_path(shared_data / "colmap/tiny_phone_scene/sparse/0").details["points"] == 256


def test_a_folder_of_photos_without_poses(photo_folder):
    given = inspect_path(photo_folder)
    assert given.kind == "photos"
    assert (given.details["photos"], given.details["width"], given.details["height"]) == (3, 1080, 1920)


def test_a_video_is_probed_for_its_size_and_length(video):
    given = inspect_path(video)
    assert given.kind == "video"
    assert (given.details["width"], given.details["height"]) == (48, 32)
    assert given.details["seconds"] == pytest.approx(2.0, abs=0.3)


def test_a_run_folder_is_recognised_by_its_task(nerf_run, classify_run):
    nerf = inspect_path(nerf_run)
    assert (nerf.kind, nerf.details["task"], nerf.details["model"], nerf.details["finished"]) == (
        "run", "nerf", "tiny", True)
    assert "psnr" in nerf.details["metrics"]
    json.dumps(nerf.details, allow_nan=False)  # strict JSON: an SSIM of NaN (8-pixel views) is None
    assert inspect_path(classify_run).details["task"] == "classify"


def test_a_modelnet_folder_is_a_dataset_of_classes(shared_data):
    given = inspect_path(shared_data / "modelnet/ModelNet10")
    assert given.kind == "clouds"
    assert given.details["classes"] == ["bathtub", "chair", "toilet"]
    assert given.details["splits"] == ["train"]


def test_several_cloud_files_are_one_set_of_clouds(shared_data):
    files = [shared_data / "pcd/pcl_bunny_ascii.pcd", shared_data / "ply/pcl_cube_binary_le.ply"]
    answer = route(files, task="classify")
    assert answer.input.kind == "clouds" and answer.input.details["files"] == 2
    assert answer.commands[-1] == f"pointfield classify predict runs/classify {files[0]} {files[1]}"


# -- cheap: headers only -------------------------------------------------------------------------


def test_files_with_headers_are_never_read_whole(shared_data, monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("inspection read a whole file")

    monkeypatch.setattr(route_inputs, "read", refuse)
    for name in ("pcd/pcl_table_scene_mug_organized.pcd", "ply/trimesh_bunny_ascii_mesh.ply",
                 "gaussians/3dgs_point_cloud_iter7000.ply", "las/autzen_trim.laz",
                 "e57/pye57_pumpAVisualReferenceImage.e57", "kitti/mmdet3d_demo/000008.bin"):
        assert inspect_path(shared_data / name).details["read"] in ("header", "size")


def test_a_hundred_million_point_file_is_described_from_its_header(tmp_path):
    path = tmp_path / "huge.ply"
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 100000000\nproperty float x\n" \
             b"property float y\nproperty float z\nend_header\n"
    with open(path, "wb") as file:
        file.write(header)
        file.truncate(len(header) + 100_000_000 * 12)  # sparse: 1.2 GB that take no disk
    answer = route(path, task="realtime")
    assert answer.input.details["points"] == 100_000_000
    assert "view shows a subset" in answer.notes[0]


def test_a_large_text_file_is_estimated_from_its_first_lines(tmp_path, monkeypatch):
    monkeypatch.setattr(route_inputs, "FULL_READ_LIMIT", 1 << 20)
    path = tmp_path / "big.xyz"
    with open(path, "wb") as file:
        file.write(b"0.125 0.25 0.5\n" * 100_000)  # 1.5 MB of 15-byte lines
    details = inspect_path(path).details
    assert details["read"] == "estimate" and details["points"] is None
    assert details["points_estimate"] == pytest.approx(100_000, rel=0.01)


# -- the rules: the task changes the answer ------------------------------------------------------


def test_a_scan_without_a_task_is_looked_at_as_a_point_cloud(shared_data):
    scan = shared_data / "pcd/pcl_table_scene_mug_organized.pcd"
    answer = route(scan)
    assert answer.representation == "point cloud" and answer.task is None
    assert answer.commands[:2] == (f"pointfield cloud info {scan}", f"pointfield view {scan}")


def test_a_scan_to_classify_goes_to_pointnet(shared_data):
    scan = shared_data / "pcd/pcl_table_scene_mug_organized.pcd"
    answer = route(scan, task="classify")
    assert answer.representation == "point cloud" and answer.task == "classify"
    assert answer.commands == ("pointfield classify train DATA --model pointnet --out runs/classify",
                               f"pointfield classify predict runs/classify {scan}")
    assert any("whole scene" in note for note in answer.notes)  # 307,200 points, organised: not one object


def test_a_lidar_tile_to_segment_uses_its_classification_field(shared_data):
    answer = route(shared_data / "las/autzen_trim.laz", task="segment the ground")
    assert answer.task == "segment"
    assert "--label-field classification" in answer.commands[0]


def test_a_scan_for_a_robot_becomes_voxels_whose_python_runs(shared_data, tmp_path, monkeypatch):
    answer = route(shared_data / "kitti/mmdet3d_demo/000008.bin", task="a robot's collision map")
    assert (answer.task, answer.representation) == ("collision", "voxels")
    monkeypatch.chdir(tmp_path)
    exec("\n".join(answer.python), {})  # noqa: S102  (the python lines the router prints)
    voxels = read_voxels(tmp_path / "000008-voxels.npz")
    assert 0 < len(voxels) < 17238  # the occupied 5 cm voxels of the 17,238-point scan
    assert f"pointfield cloud voxelize {shared_data / 'kitti/mmdet3d_demo/000008.bin'}" in answer.commands[1]


def test_a_lidar_sweep_for_a_robot_gets_an_occupancy_command_that_runs(tmp_path, monkeypatch, capsys):
    from pointfield.volumes.occupancy import read_octomap

    # A sweep from the sensor at the origin to the walls of a box 4 m around it, as a KITTI .bin holds it.
    direction = np.random.default_rng(0).normal(size=(3000, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = direction * (3.975 / np.abs(direction).max(axis=1))[:, None]
    sweep = tmp_path / "sweep.bin"
    np.concatenate([points, np.zeros((len(points), 1))], axis=1).astype(np.float32).tofile(sweep)
    answer = route(sweep, task="a robot's collision map")
    command = next(c for c in answer.commands if c.startswith("pointfield cloud occupancy"))
    monkeypatch.chdir(tmp_path)
    assert main(shlex.split(command)[1:]) == 0  # as printed
    occupancy = read_octomap(tmp_path / "sweep.bt")
    # Halfway along a ray: free; where it ended: occupied; past the wall: unknown.
    assert occupancy.state(np.array([points[0] / 2, points[0], points[0] * 1.5])).tolist() == [0, 1, -1]


def test_several_scans_for_a_robot_are_aligned_then_mapped_from_the_poses(shared_data):
    scans = [shared_data / "registration/pcl_bun0.pcd", shared_data / "registration/pcl_bun4.pcd"]
    answer = route(scans, task="collision")
    assert answer.representation == "voxels"
    assert answer.commands[0].startswith("pointfield cloud align") and "--out clouds.ply" in answer.commands[0]
    assert "cloud occupancy --poses clouds.poses.json" in answer.commands[1]  # the file align writes beside clouds.ply
    parser = build_parser()
    for command in answer.commands:
        parser.parse_args(shlex.split(command)[1:])


def test_a_scan_for_a_mesh_gets_python_that_writes_it_with_normals(shared_data, tmp_path, monkeypatch):
    answer = route(shared_data / "kitti/semantickitti_seq00/000000.bin", task="mesh")
    assert answer.representation == "mesh"
    monkeypatch.chdir(tmp_path)
    exec("\n".join(answer.python), {})  # noqa: S102  (the python lines the router prints)
    cloud = pointfield.read(tmp_path / "000000-normals.ply")
    assert len(cloud) == 100_000 and "normals" in cloud.fields  # thinned from 124,668 points


def test_a_modelnet_mesh_to_classify_trains_on_its_modelnet_folder(shared_data):
    chair = shared_data / "modelnet/ModelNet10/chair/train/chair_0001.off"
    answer = route(chair, task="classify")
    assert answer.representation == "point cloud"
    assert answer.commands[0] == (f"pointfield classify train {shared_data / 'modelnet/ModelNet10'} "
                                  "--model pointnet --out runs/ModelNet10")
    assert answer.commands[1] == f"pointfield classify predict runs/ModelNet10 {chair}"


def test_a_mesh_for_a_game_engine_is_converted_and_its_python_writes_glb(shared_data, tmp_path, monkeypatch):
    answer = route(shared_data / "ply/pcl_cube_binary_le.ply", task="mesh for a game engine")
    assert answer.representation == "mesh"
    monkeypatch.chdir(tmp_path)
    exec("\n".join(answer.python), {})  # noqa: S102  (the python lines the router prints)
    assert (tmp_path / "pcl_cube_binary_le.glb").stat().st_size > 0


def test_photos_without_a_task_become_a_hash_grid_field(photo_folder):
    answer = route(photo_folder)
    assert answer.representation == "radiance field"
    assert answer.commands[0] == f"pointfield scene from-images '{photo_folder}' --out my-photos-scene"
    assert answer.commands[1] == ("pointfield nerf train my-photos-scene --model ngp --downscale 8 "
                                  "--holdout-every 10 --out runs/my-photos")
    assert any("3 photos" in note for note in answer.notes)


def test_photos_for_a_game_engine_become_an_exported_mesh(photo_folder):
    answer = route(photo_folder, task="mesh for a game engine")
    assert (answer.task, answer.representation) == ("mesh", "mesh")
    assert [command.split()[1:3] for command in answer.commands] == [
        ["scene", "from-images"], ["nerf", "train"], ["nerf", "export"]]
    assert "--model ngp" in answer.commands[1]
    assert answer.commands[2] == "pointfield nerf export runs/my-photos --mesh my-photos.glb --faces 200000"


def test_photos_for_real_time_viewing_become_splats(photo_folder):
    answer = route(photo_folder, task="real-time viewing")
    assert (answer.task, answer.representation) == ("realtime", "Gaussian splats")
    assert answer.commands[1:] == (
        "pointfield splat train my-photos-scene --downscale 8 --holdout-every 10 --out runs/my-photos-splats",
        "pointfield splat export runs/my-photos-splats --out my-photos-splats.ply",
        "pointfield view my-photos-splats.ply",
    )


def test_a_video_is_posed_first(video):
    answer = route(video, task="reconstruct")
    assert answer.commands[0] == f"pointfield scene from-video {video} --out walk-scene --frames 150"
    assert answer.commands[1].startswith("pointfield nerf train walk-scene --model ngp")


def test_new_views_of_an_object_use_the_hash_grid_and_of_a_capture_with_points_splats(shared_data):
    lego = route(shared_data / "nerf/lego_blender", task="novel views")
    assert lego.representation == "radiance field"
    assert lego.commands[0] == (f"pointfield nerf train {shared_data / 'nerf/lego_blender'} --model ngp "
                                "--downscale 4 --holdout-every 10 --out runs/lego_blender")
    phone = route(shared_data / "colmap/tiny_phone_scene/sparse/0", task="novel views")
    assert phone.representation == "Gaussian splats"
    assert phone.commands[0].endswith("--out runs/tiny_phone_scene-splats")


def test_a_scene_with_a_test_split_is_not_held_out_again(shared_data):
    answer = route(shared_data / "nerf/lego_test_fixture")  # train and val splits
    assert "--holdout-every" not in answer.commands[0]


def test_an_object_is_meshed_from_its_density_and_a_real_capture_from_fused_depth(shared_data):
    lego = route(shared_data / "nerf/lego_blender", task="mesh")
    assert lego.commands[-1] == ("pointfield nerf export runs/lego_blender --mesh lego_blender.glb --faces 200000 "
                                 "--method density")
    assert "density" in lego.reason
    fox = route(shared_data / "nerf/fox_instant_ngp", task="mesh")
    assert fox.commands[-1] == "pointfield nerf export runs/fox_instant_ngp --mesh fox_instant_ngp.glb --faces 200000"


def test_splats_are_viewed_as_they_are_and_meshed_from_their_run(shared_data):
    path = shared_data / "gaussians/3dgs_point_cloud_iter7000.ply"
    assert route(path).representation == "Gaussian splats"
    assert route(path).commands[0] == f"pointfield view {path}"
    mesh = route(path, task="mesh")
    assert mesh.commands == ("pointfield splat export RUN --mesh 3dgs_point_cloud_iter7000.glb --faces 200000",)
    assert route(path, task="classify").commands[-1] == f"pointfield classify predict runs/classify {path}"


def test_a_modelnet_folder_trains_a_classifier(shared_data):
    folder = shared_data / "modelnet/ModelNet10"
    answer = route(folder)
    assert answer.commands[0] == f"pointfield classify train {folder} --model pointnet --out runs/ModelNet10"


def test_a_nerf_run_renders_meshes_and_points_to_the_hash_grid(nerf_run):
    answer = route(nerf_run)
    assert answer.representation == "radiance field"
    assert answer.commands[0] == f"pointfield nerf eval {nerf_run}"
    assert any("--model ngp" in note for note in answer.notes)  # a TinyNeRF run: the fast field is ngp
    assert route(nerf_run, task="mesh").commands == (
        f"pointfield nerf export {nerf_run} --mesh cube-tiny.glb --faces 200000",)
    realtime = route(nerf_run, task="realtime")
    assert realtime.representation == "Gaussian splats" and realtime.commands[0].startswith("pointfield splat train")


def test_a_classify_run_is_evaluated_and_applied(classify_run):
    answer = route(classify_run)
    assert answer.commands == (f"pointfield classify eval {classify_run}",
                               f"pointfield classify predict {classify_run} FILE")


ROUTED = [
    ("pcd/pcl_table_scene_mug_organized.pcd", None), ("pcd/pcl_table_scene_mug_organized.pcd", "classify"),
    ("las/autzen_trim.laz", "segment"), ("las/simple.las", "collision"), ("las/simple.las", "measure"),
    ("xyz_pts/pdal_bunny_8.pts", "mesh"), ("pcd/pcl_bunny_ascii.pcd", "novel views"),
    ("modelnet/ModelNet10/chair/train/chair_0001.off", "segment"),
    ("modelnet/ModelNet10/chair/train/chair_0001.off", "mesh"),
    ("gaussians/3dgs_point_cloud_iter7000.ply", None), ("gaussians/3dgs_point_cloud_iter7000.ply", "mesh"),
    ("nerf/lego_blender", None), ("nerf/lego_blender", "mesh"), ("nerf/fox_instant_ngp", "realtime"),
    ("nerf/fox_instant_ngp", "measure"), ("nerf/fox_instant_ngp", "classify"), ("llff/milk", "collision"),
    ("colmap/tiny_phone_scene/fotos", None), ("colmap/tiny_phone_scene/fotos", "segment"),
    ("modelnet/ModelNet10", None), ("modelnet/ModelNet10", "segment"), ("modelnet/ModelNet10", "realtime"),
]


@pytest.mark.parametrize(("name", "task"), ROUTED)
def test_every_suggested_command_is_a_real_pointfield_command(shared_data, name, task):
    parser = build_parser()
    answer = route(shared_data / name, task=task)
    assert answer.commands
    for command in answer.commands:
        words = shlex.split(command)
        assert words[0] == "pointfield"
        parser.parse_args(words[1:])  # an unknown command or option exits


def test_the_runs_commands_are_real_too(nerf_run, classify_run):
    parser = build_parser()
    for run in (nerf_run, classify_run):
        for task in (None, "mesh", "measure", "collision", "realtime", "classify"):
            for command in route(run, task=task).commands:
                parser.parse_args(shlex.split(command)[1:])


@pytest.mark.parametrize(("words", "task"), [
    ("classify", "classify"), ("what object is this", "classify"), ("segment the parts", "segment"),
    ("reconstruct it", "reconstruct"), ("novel views", "novel-views"), ("render a turntable", "novel-views"),
    ("mesh for a game engine", "mesh"), ("import into Unity", "mesh"), ("measure the room", "measure"),
    ("real-time viewing", "realtime"), ("view it in VR", "realtime"), ("a robot's collision map", "collision"),
    ("real-time views of the reconstruction", "realtime"), ("novel-views", "novel-views"), (None, None),
])
def test_task_words_name_a_task(words, task):
    assert parse_task(words) == task


def test_words_that_name_no_task_are_refused_with_the_list():
    with pytest.raises(PointfieldError, match="names no task .* classify .* collision"):
        parse_task("bake a cake")


# -- errors --------------------------------------------------------------------------------------


def test_a_path_that_does_not_exist_is_one_clear_error(tmp_path, capsys):
    missing = tmp_path / "nowhere.ply"
    with pytest.raises(PointfieldError, match="no such file or folder"):
        route(missing)
    code, out, err = _cli(capsys, missing)
    assert code == 1 and out == ""
    assert err.strip().splitlines() == [f"pointfield: error: {missing}: no such file or folder"]


def test_a_file_it_cannot_identify_is_one_clear_error(tmp_path, capsys):
    unknown = tmp_path / "notes.docx"
    unknown.write_bytes(b"PK\x05\x06 not a point cloud")
    with pytest.raises(PointfieldError, match="cannot identify this file"):
        route(unknown)
    code, out, err = _cli(capsys, unknown)
    assert code == 1 and out == "" and "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"pointfield: error: {unknown}: pointfield cannot identify")


def test_a_folder_of_nothing_pointfield_reads_is_an_error(tmp_path):
    (tmp_path / "readme.md").write_text("hello")
    with pytest.raises(PointfieldError, match="cannot identify this folder"):
        route(tmp_path)


def test_a_file_without_coordinates_is_an_error(shared_data):
    with pytest.raises(PointfieldError, match="without x, y, z coordinates"):
        route(shared_data / "pcd/pcl_brisk_descriptors_count64.pcd")


def test_inputs_of_different_kinds_are_refused(shared_data, photo_folder):
    with pytest.raises(PointfieldError, match="one kind of input at a time"):
        route([shared_data / "las/simple.las", photo_folder / "0001.jpg"])


def test_a_bad_task_is_refused_before_any_file_is_opened(tmp_path, capsys):
    code, _, err = _cli(capsys, tmp_path / "missing.ply", "--task", "bake a cake")
    assert code == 1 and "names no task" in err


# -- the command line ----------------------------------------------------------------------------


def test_json_has_the_stable_schema(shared_data, capsys):
    splats = shared_data / "gaussians/3dgs_point_cloud_iter7000.ply"
    code, out, _ = _cli(capsys, splats, "--task", "real-time viewing", "--json")
    assert code == 0
    answer = json.loads(out)
    assert set(answer) == {"schema", "inputs", "input_kind", "details", "task", "task_words", "representation",
                           "reason", "commands", "python", "notes"}
    assert answer["schema"] == SCHEMA
    assert (answer["input_kind"], answer["task"], answer["representation"]) == ("splats", "realtime", "Gaussian splats")
    assert answer["task_words"] == "real-time viewing"
    assert answer["inputs"] == [str(splats)] and answer["details"]["points"] == 9080
    assert answer["commands"][0] == f"pointfield view {splats}"


def test_text_names_the_input_the_representation_and_the_steps(shared_data, capsys):
    scan = shared_data / "kitti/semantickitti_seq00/000000.bin"
    code, out, _ = _cli(capsys, scan, "--task", "collision map for a robot")
    assert code == 0
    lines = out.splitlines()
    assert lines[0].startswith("input") and "124,668 points" in lines[0]
    assert lines[1].split() == ["task", "collision"]
    assert lines[2].split() == ["representation", "voxels"]
    assert lines[3].startswith("why")
    assert lines[4].split() == ["next", "pointfield", "cloud", "info", str(scan)]
    assert out == format_route(route(scan, task="collision map for a robot")) + "\n"


def test_help_lists_route(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "route" in capsys.readouterr().out
