"""Every point-cloud and mesh file in ../shared/data reads with the count its MANIFEST.md gives."""

from __future__ import annotations

import pytest

import pointfield
from pointfield import Mesh, Records

# (path under shared/data, points or records, faces or None, reader options) — from MANIFEST.md.
MANIFEST_COUNTS = [
    ("pcd/pcl_bunny_ascii.pcd", 397, None, {}),
    ("pcd/pcl_bun0_ascii_normals.pcd", 397, None, {}),
    ("pcd/pcl_curve_close_binary.pcd", 110, None, {}),
    ("pcd/pcl_office1_keypoints_binary.pcd", 1318, None, {}),
    ("pcd/pcl_colored_cloud_binary.pcd", 1000, None, {}),
    ("pcd/pcl_milk_binary_compressed.pcd", 13704, None, {}),
    ("pcd/pcl_milk_color_binary_compressed.pcd", 13704, None, {}),
    ("pcd/pcl_logo_binary_compressed.pcd", 12909, None, {}),
    ("pcd/pcl_cturtle_binary_compressed.pcd", 167198, None, {}),
    ("pcd/pcl_table_scene_mug_organized.pcd", 307200, None, {}),
    ("pcd/pcl_brisk_descriptors_count64.pcd", 1534, None, {}),
    ("pcd/pdal_utm17_space_ascii.pcd", 10, None, {}),
    ("ply/trimesh_bunny_ascii_mesh.ply", 8171, 16301, {}),
    ("ply/trimesh_fuze_binary_le_colors_texcoord.ply", 502, 1000, {}),
    ("ply/trimesh_reference_binary_le_rgba.ply", 845, 1610, {}),
    ("ply/trimesh_points_ascii.ply", 5, None, {}),
    ("ply/trimesh_points_bin.ply", 5, None, {}),
    ("ply/trimesh_featuretype_ascii_normals.ply", 5096, 3476, {}),
    ("ply/pcl_cube_binary_le.ply", 24, 12, {}),
    ("ply/plyfile_tet_ascii_face_colors.ply", 4, 4, {}),
    ("ply/pcu_truck_binary_le_rgba.ply", 5240, 9868, {}),
    ("ply/pcu_duplicated_pcloud_double_normals.ply", 5395, None, {}),
    ("ply/pcu_bunny_poisson_binary_le.ply", 2885, 5766, {}),
    ("ply/pdal_simple_binary_cloudcompare.ply", 3, None, {}),
    ("ply/pdal_sized_dims_ascii.ply", 1, None, {}),
    ("ply/armadillo_points_normals_ascii.ply", 38294, None, {}),
    ("gaussians/3dgs_point_cloud_iter7000.ply", 9080, None, {}),
    ("las/simple.las", 1065, None, {}),
    ("las/simple.laz", 1065, None, {}),
    ("las/test1_4.las", 1000, None, {}),
    ("las/1_4_w_evlr.laz", 1000, None, {}),
    ("las/extrabytes.las", 1065, None, {}),
    ("las/plane.laz", 28185, None, {}),
    ("las/simple.copc.laz", 1065, None, {}),
    ("las/autzen_trim.laz", 110000, None, {}),
    ("modelnet/ModelNet10/bathtub/train/bathtub_0001.off", 3514, 3546, {}),
    ("modelnet/ModelNet10/bathtub/train/bathtub_0002.off", 700, 664, {}),
    ("modelnet/ModelNet10/bathtub/train/bathtub_0004.off", 2842, 3519, {}),
    ("modelnet/ModelNet10/chair/train/chair_0001.off", 2382, 2234, {}),
    ("modelnet/ModelNet10/chair/train/chair_0002.off", 192, 96, {}),
    ("modelnet/ModelNet10/toilet/train/toilet_0001.off", 3739, 6341, {}),
    ("modelnet/ModelNet10/toilet/train/toilet_0002.off", 11098, 17826, {}),
    ("modelnet/ModelNet40/airplane/train/airplane_0006.off", 13091, 29589, {}),
    ("kitti/mmdet3d_demo/000008.bin", 17238, None, {}),
    ("kitti/semantickitti_seq00/000000.bin", 124668, None, {}),
    ("other_pointclouds/scannet_scene0000_00_xyzrgb.bin", 40684, None, {"columns": 6}),
    ("xyz_pts/trimesh_points_cloudcompare.xyz", 101, None, {}),
    ("xyz_pts/trimesh_points_agisoft.xyz", 100, None, {}),
    ("xyz_pts/pdal_gdal_data.xyz", 400, None, {}),
    ("xyz_pts/pdal_autzen.pts", 10, None, {}),
    ("xyz_pts/pdal_bunny_8.pts", 8, None, {}),  # the count line's 8 of its 9 rows, as PDAL
    ("xyz_pts/pdal_test.pts", 19, None, {}),
    ("e57/pye57_testWithNormals.e57", 2, None, {}),
    ("e57/pye57_pumpAVisualReferenceImage.e57", 155201, None, {}),
    ("e57/pdal_A4.e57", 4, None, {}),
    ("e57/pdal_A_B.e57", 6, None, {}),
]

POINT_CLOUD_FOLDERS = ("pcd", "ply", "las", "modelnet", "kitti", "other_pointclouds", "xyz_pts", "e57")


def test_the_table_lists_every_point_cloud_file(shared_data):
    on_disk = {
        str(p.relative_to(shared_data))
        for folder in POINT_CLOUD_FOLDERS
        for p in (shared_data / folder).rglob("*")
        if p.is_file() and p.suffix.lower() not in {".png", ".txt"}
    } | {str(p.relative_to(shared_data)) for p in (shared_data / "gaussians").glob("*.ply")}
    assert on_disk == {row[0] for row in MANIFEST_COUNTS}


@pytest.mark.parametrize(("relative", "count", "faces", "options"), MANIFEST_COUNTS, ids=lambda v: str(v))
def test_real_file_reads_with_its_manifest_count(shared_data, relative, count, faces, options):
    cloud = pointfield.read(shared_data / relative, **options)
    assert len(cloud) == count
    assert cloud.metadata["format"]
    assert cloud.metadata["encoding"]
    if faces is None:
        assert not isinstance(cloud, Mesh)
    else:
        assert isinstance(cloud, Mesh)
        assert len(cloud.faces) == faces
    if not isinstance(cloud, Records):
        assert cloud.points.shape == (count, 3)
