"""Photos are decoded and checked before COLMAP sees them: natural order, bad files named, sizes kept."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from PIL import Image

from pointfield.scenes.sfm import PosingError, gather_photos


def photo(path, size=(96, 80), seed=0, **save):
    pixels = np.random.default_rng(seed).integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
    Image.fromarray(pixels).save(path, **save)
    return path


def test_a_folder_gives_its_images_in_natural_order_and_skips_other_files_with_one_warning(tmp_path):
    for name in ("10.jpg", "2.jpg", "1.png"):
        photo(tmp_path / name)
    (tmp_path / "notes.txt").write_text("not a photo")
    (tmp_path / "sidecar.xmp").write_text("<x/>")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        photos = gather_photos(tmp_path)
    assert [p.path.name for p in photos] == ["1.png", "2.jpg", "10.jpg"]
    assert len(caught) == 1 and "skipped 2 files" in str(caught[0].message)


def test_a_list_keeps_its_order_and_mixed_sizes_are_returned_with_their_sizes(tmp_path):
    paths = [photo(tmp_path / "b.jpg", (96, 80)), photo(tmp_path / "a.jpg", (120, 90)), photo(tmp_path / "c.png")]
    photos = gather_photos(paths)
    assert [p.path for p in photos] == paths
    assert [p.size for p in photos] == [(96, 80), (120, 90), (96, 80)]


def test_too_few_missing_tiny_and_listed_non_images_are_refused(tmp_path):
    photo(tmp_path / "1.jpg"), photo(tmp_path / "2.jpg")
    with pytest.raises(PosingError, match="found 2 images .* at least 3 overlapping photos"):
        gather_photos(tmp_path)
    with pytest.raises(PosingError, match="no such folder or file"):
        gather_photos(tmp_path / "missing")
    tiny = photo(tmp_path / "3.jpg", (40, 40))
    with pytest.raises(PosingError, match="3.jpg: 40x40 pixels is too small"):
        gather_photos(tmp_path)
    tiny.unlink()
    notes = tmp_path / "notes.txt"
    notes.write_text("x")
    with pytest.raises(PosingError, match="notes.txt: not an image"):
        gather_photos([tmp_path / "1.jpg", tmp_path / "2.jpg", notes])


def test_corrupt_and_truncated_images_are_named_with_a_count_of_the_others(tmp_path):
    for index in range(3):
        photo(tmp_path / f"{index}.jpg", seed=index)
    (tmp_path / "3.jpg").write_text("shopping list")
    full = photo(tmp_path / "4.png", (200, 200)).read_bytes()
    (tmp_path / "4.png").write_bytes(full[: len(full) * 6 // 10])
    with pytest.raises(PosingError, match=r"3.jpg: not an image .* \(and 1 more bad file\)"):
        gather_photos(tmp_path)
    (tmp_path / "3.jpg").unlink()
    with pytest.raises(PosingError, match="4.png: truncated or corrupt image"):
        gather_photos(tmp_path)
    jpeg = photo(tmp_path / "5.jpg", (200, 200)).read_bytes()
    (tmp_path / "4.png").unlink()
    (tmp_path / "5.jpg").write_bytes(jpeg[: len(jpeg) * 6 // 10])
    with pytest.raises(PosingError, match="5.jpg: truncated or corrupt image"):
        gather_photos(tmp_path)


def test_an_exif_rotation_is_flagged(tmp_path):
    exif = Image.Exif()
    exif[0x0112] = 6  # rotate 90 degrees clockwise to display
    photo(tmp_path / "0.jpg", exif=exif.tobytes())
    photo(tmp_path / "1.jpg"), photo(tmp_path / "2.jpg")
    assert [p.exif_rotated for p in gather_photos(tmp_path)] == [True, False, False]
