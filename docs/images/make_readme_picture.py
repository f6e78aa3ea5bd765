"""Regenerate docs/images/clouds.png, the README's picture, from files in ../shared/data.

Run: ``.venv/bin/python docs/images/make_readme_picture.py``
"""

from pathlib import Path

import pointfield
from pointfield.viz import image_grid, render_cloud, save_image

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
FILES = {
    "KITTI velodyne scan (.bin)": "kitti/semantickitti_seq00/000000.bin",
    "PCL milk carton (PCD, LZF)": "pcd/pcl_milk_color_binary_compressed.pcd",
    "ModelNet chair (OFF mesh)": "modelnet/ModelNet10/chair/train/chair_0001.off",
    "autzen lidar tile (LAZ)": "las/autzen_trim.laz",
}

images = [render_cloud(pointfield.read(DATA / rel), width=480, height=360) for rel in FILES.values()]
save_image(ROOT / "docs" / "images" / "clouds.png", image_grid(images, list(FILES), columns=4))
