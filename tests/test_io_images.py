"""load_image / load_pair on real files of every kind, and every way a file can be wrong."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereogeo_cli.errors import EXIT_BAD_INPUT, EXIT_CALIBRATION_FAILED, StereoGeoError
from stereogeo_cli.io import check_pair, load_image, load_pair


def rgb_image(h: int = 80, w: int = 100, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def save(path: Path, image: np.ndarray, params: list[int] | None = None) -> Path:
    """Write with OpenCV (which takes BGR) so the file holds ``image`` as RGB."""
    if image.ndim == 3 and image.shape[2] == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_RGBA2BGRA)
    assert cv2.imwrite(str(path), image, params or [])
    return path


def user_error(path, match: str) -> StereoGeoError:
    with pytest.raises(StereoGeoError, match=match) as err:
        load_image(path)
    assert err.value.exit_code == EXIT_BAD_INPUT
    message = str(err.value)
    assert "\n" not in message and str(path) in message
    return err.value


@pytest.mark.parametrize("ext", [".png", ".bmp", ".tiff", ".webp"])
def test_lossless_formats_load_as_rgb(tmp_path, ext):
    image = rgb_image()
    params = [cv2.IMWRITE_WEBP_QUALITY, 101] if ext == ".webp" else None  # 101: lossless
    loaded = load_image(save(tmp_path / f"a{ext}", image, params))
    assert loaded.dtype == np.uint8 and loaded.shape == (80, 100, 3)
    np.testing.assert_array_equal(loaded, image)


def test_jpeg_loads_as_rgb(tmp_path):
    image = np.zeros((80, 100, 3), np.uint8)
    image[..., 0] = 200  # red
    loaded = load_image(save(tmp_path / "a.jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95]))
    assert loaded.shape == (80, 100, 3)
    assert np.abs(loaded.astype(int) - image).max() <= 3


@pytest.mark.parametrize("ext", [".png", ".tiff"])
def test_16_bit_is_scaled_to_8_bit(tmp_path, ext):
    image8 = rgb_image()
    image16 = image8.astype(np.uint16) * 257  # 255 → 65535
    image16[0, 0] = [1000, 128, 65534]  # round(v · 255 / 65535): 4, 0, 255
    loaded = load_image(save(tmp_path / f"a{ext}", image16))
    expected = image8.copy()
    expected[0, 0] = [4, 0, 255]
    np.testing.assert_array_equal(loaded, expected)


def test_grey_becomes_three_equal_channels(tmp_path):
    grey = rgb_image()[..., 0]
    loaded = load_image(save(tmp_path / "g.png", grey))
    assert loaded.shape == (80, 100, 3)
    for c in range(3):
        np.testing.assert_array_equal(loaded[..., c], grey)


def test_grey_16_bit(tmp_path):
    grey = np.full((70, 70), 65535, np.uint16)
    grey[:, :35] = 257 * 10
    loaded = load_image(save(tmp_path / "g16.png", grey))
    assert loaded.shape == (70, 70, 3)
    assert set(np.unique(loaded)) == {10, 255}


@pytest.mark.parametrize("ext", [".png", ".webp", ".tiff"])
def test_alpha_is_dropped(tmp_path, ext):
    image = rgb_image()
    alpha = np.full((80, 100, 1), 128, np.uint8)
    alpha[:40] = 255
    params = [cv2.IMWRITE_WEBP_QUALITY, 101] if ext == ".webp" else None
    loaded = load_image(save(tmp_path / f"a{ext}", np.concatenate([image, alpha], axis=2), params))
    np.testing.assert_array_equal(loaded, image)


def test_float_tiff_is_taken_as_zero_to_one(tmp_path):
    image = np.full((70, 70, 3), 0.5, np.float32)
    image[0, 0] = [2.0, -1.0, 1.0]
    loaded = load_image(save(tmp_path / "f.tiff", image))
    assert loaded[1, 1].tolist() == [128, 128, 128]
    assert loaded[0, 0].tolist() == [255, 0, 255]


def _with_exif_orientation(jpeg: bytes, orientation: int) -> bytes:
    """Insert an APP1 Exif segment with only the Orientation tag (0x0112) after SOI."""
    ifd = struct.pack(">H", 1) + struct.pack(">HHIHH", 0x0112, 3, 1, orientation, 0) + struct.pack(">I", 0)
    payload = b"Exif\x00\x00" + b"MM\x00*\x00\x00\x00\x08" + ifd
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + jpeg[2:]


def test_exif_orientation_is_applied(tmp_path):
    image = np.zeros((80, 100, 3), np.uint8)
    image[:16, :16] = 255  # a white block at the stored top-left
    ok, jpeg = cv2.imencode(".jpg", image)
    path = tmp_path / "rotated.jpg"
    path.write_bytes(_with_exif_orientation(jpeg.tobytes(), 6))  # 6: display rotated 90° clockwise
    loaded = load_image(path)
    assert loaded.shape == (100, 80, 3)
    ys, xs = np.nonzero(loaded[..., 0] > 128)
    assert ys.mean() < 20 and xs.mean() > 60  # the block is now at the top-right
    # orientation 1 leaves it alone
    path.write_bytes(_with_exif_orientation(jpeg.tobytes(), 1))
    assert load_image(path).shape == (80, 100, 3)


def test_missing_file(tmp_path):
    user_error(tmp_path / "nope.png", "not found")


def test_folder(tmp_path):
    user_error(tmp_path, "is a folder")


def test_empty_file(tmp_path):
    path = tmp_path / "empty.png"
    path.write_bytes(b"")
    user_error(path, "empty")


def test_not_an_image(tmp_path):
    path = tmp_path / "notes.png"
    path.write_text("these are not pixels\n" * 20)
    user_error(path, "not an image")


@pytest.mark.parametrize("keep", [0.5, 0.98, -12, -3])
def test_truncated_png(tmp_path, capfd, keep):
    data = (save(tmp_path / "full.png", rgb_image(200, 300))).read_bytes()
    cut = int(len(data) * keep) if isinstance(keep, float) else len(data) + keep
    path = tmp_path / "cut.png"
    path.write_bytes(data[:cut])
    user_error(path, "truncated")
    assert capfd.readouterr().err == ""  # no libpng noise: the file is never decoded


@pytest.mark.parametrize("keep", [0.3, 0.9, -2])
def test_truncated_jpeg(tmp_path, keep):
    data = save(tmp_path / "full.jpg", rgb_image(200, 300)).read_bytes()
    path = tmp_path / "cut.jpg"
    path.write_bytes(data[: int(len(data) * keep) if isinstance(keep, float) else len(data) + keep])
    user_error(path, "truncated")


def test_jpeg_with_thumbnail_end_marker_and_trailer_still_loads(tmp_path):
    data = save(tmp_path / "full.jpg", rgb_image(), [cv2.IMWRITE_JPEG_QUALITY, 95]).read_bytes()
    # an APP1 segment holding FF D9 (as an embedded thumbnail does), and bytes after the end marker
    payload = b"Exif\x00\x00" + b"\xff\xd8thumb\xff\xd9"
    app1 = b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload
    path = tmp_path / "thumb.jpg"
    path.write_bytes(data[:2] + app1 + data[2:] + b"TRAILER")
    assert load_image(path).shape == (80, 100, 3)
    path.write_bytes(data[:2] + app1 + data[2 : len(data) // 2])
    user_error(path, "truncated")


@pytest.mark.parametrize("ext", [".webp", ".bmp", ".tiff"])
def test_truncated_other_formats(tmp_path, ext):
    params = [cv2.IMWRITE_WEBP_QUALITY, 101] if ext == ".webp" else None
    data = save(tmp_path / f"full{ext}", rgb_image(200, 300), params).read_bytes()
    path = tmp_path / f"cut{ext}"
    path.write_bytes(data[: len(data) // 2])
    user_error(path, "truncated|cannot read")


@pytest.mark.parametrize(("h", "w"), [(63, 100), (100, 63), (1, 1)])
def test_too_small(tmp_path, h, w):
    user_error(save(tmp_path / "small.png", rgb_image(h, w)), "too small")


def test_smallest_accepted(tmp_path):
    assert load_image(save(tmp_path / "ok.png", rgb_image(64, 64))).shape == (64, 64, 3)


def test_pair(tmp_path):
    left = save(tmp_path / "l.png", rgb_image(seed=1))
    right = save(tmp_path / "r.png", rgb_image(90, 120, seed=2))
    a, b = load_pair(left, right)
    assert a.shape == (80, 100, 3) and b.shape == (90, 120, 3)


def test_pair_of_the_same_file(tmp_path):
    left = save(tmp_path / "l.png", rgb_image())
    with pytest.raises(StereoGeoError, match="same file") as err:
        load_pair(left, tmp_path / "." / "l.png")
    assert err.value.exit_code == EXIT_BAD_INPUT


def test_pair_of_identical_images(tmp_path):
    left = save(tmp_path / "l.png", rgb_image())
    right = save(tmp_path / "r.png", rgb_image())
    with pytest.raises(StereoGeoError, match="same image") as err:
        load_pair(left, right)
    assert err.value.exit_code == EXIT_BAD_INPUT


@pytest.mark.parametrize("colour", [(90, 90, 90), (200, 0, 0)])
def test_blank_image_cannot_be_calibrated(colour):
    blank = np.broadcast_to(np.array(colour, np.uint8), (80, 100, 3))
    with pytest.raises(StereoGeoError, match="right is blank") as err:
        check_pair(rgb_image(), blank)
    assert err.value.exit_code == EXIT_CALIBRATION_FAILED
    dark_but_textured = (rgb_image() // 32).astype(np.uint8)  # values 0..7
    check_pair(dark_but_textured, rgb_image(seed=3))


def test_missing_right_image_is_named(tmp_path):
    left = save(tmp_path / "l.png", rgb_image())
    with pytest.raises(StereoGeoError, match="r.png"):
        load_pair(left, tmp_path / "r.png")
