"""Loading the user's images: any file OpenCV decodes, returned as H x W x 3 uint8 RGB as the user sees it.

- Formats: whatever OpenCV's ``imdecode`` reads — PNG, JPEG, TIFF, BMP, WebP (and PPM/PGM, ...).
- Depth: 8-bit as is; 16-bit scaled to 8-bit with rounding (65535 → 255); floating point taken as [0, 1].
- Channels: grey is repeated to RGB; **alpha is dropped** (the colour channels are what the camera saw;
  a stereo camera's frames carry no meaningful transparency).
- EXIF orientation is **applied**, as OpenCV's ``imread`` does by default (and image viewers do): the
  calibration — size, focal, principal point, roll — describes the image as displayed. A portrait JPEG
  stored landscape with an orientation tag is calibrated as a portrait image. To calibrate the raw sensor
  grid instead, remove the tag (e.g. ``exiftool -Orientation= file.jpg``).
- Truncated files are rejected before decoding (decoders may otherwise return a partly grey image): PNG
  must reach its IEND chunk, JPEG must have its end-of-image marker after the first scan, WebP and BMP
  must be as long as their headers say.

Every problem raises :class:`StereoGeoError` (exit code 2) with one line naming the file; a blank pair
raises :class:`CalibrationFailed` (exit code 3).
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np

from stereogeo_cli.errors import CalibrationFailed, StereoGeoError

MIN_SIDE = 64  # pixels; smaller images carry too little to calibrate from
BLANK_STD = 1.0  # standard deviation of every channel (0-255) below which an image is blank

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as an array [H x W x 3] uint8, RGB, EXIF orientation applied.

    Raises :class:`StereoGeoError` (exit code 2) for a missing, empty, truncated or undecodable file, a
    folder, an unsupported pixel type, or an image smaller than 64 pixels on a side.
    """
    import cv2

    path = Path(path)
    data = _read_bytes(path)
    problem = _truncation(data)
    if problem:
        raise StereoGeoError(f"{path} is truncated ({problem}); the file is incomplete")
    # ANYDEPTH keeps 16 bits; ANYCOLOR keeps grey as one channel and drops alpha; both, unlike
    # IMREAD_UNCHANGED, let OpenCV apply the EXIF orientation.
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    except cv2.error:
        image = None
    finally:
        cv2.utils.logging.setLogLevel(level)
    if image is None or image.size == 0:
        raise StereoGeoError(f"cannot read {path}: not an image, or a format OpenCV cannot decode")
    image = _to_uint8(image, path)
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    elif image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    else:
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    h, w = image.shape[:2]
    if min(w, h) < MIN_SIDE:
        raise StereoGeoError(f"{path} is too small ({w}x{h} pixels); each side needs at least {MIN_SIDE}")
    return image


def check_pair(left: np.ndarray, right: np.ndarray, names: tuple[str, str] = ("left", "right")) -> None:
    """Check two loaded images [H x W x 3] uint8 can make a stereo pair; ``names`` appear in messages.

    Identical images raise :class:`StereoGeoError` (exit code 2); a blank (uniform) image raises
    :class:`CalibrationFailed` (exit code 3). Different sizes are fine.
    """
    if left.shape == right.shape and np.array_equal(left, right):
        raise StereoGeoError(f"{names[0]} and {names[1]} are the same image; a stereo pair needs two views")
    for image, name in zip((left, right), names, strict=True):
        if float(image[::4, ::4].reshape(-1, image.shape[-1]).std(axis=0).max()) < BLANK_STD:
            raise CalibrationFailed(f"{name} is blank (one uniform colour); nothing to calibrate from")


def load_pair(left_path: str | os.PathLike, right_path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """:func:`load_image` both files, then :func:`check_pair`; returns (left, right) [H x W x 3] uint8 RGB."""
    left_path, right_path = Path(left_path), Path(right_path)
    if left_path.exists() and right_path.exists() and left_path.resolve() == right_path.resolve():
        raise StereoGeoError(f"left and right are the same file ({left_path}); a stereo pair needs two views")
    left, right = load_image(left_path), load_image(right_path)
    check_pair(left, right, (str(left_path), str(right_path)))
    return left, right


def _read_bytes(path: Path) -> bytes:
    if not path.exists():
        raise StereoGeoError(f"image not found: {path}")
    if path.is_dir():
        raise StereoGeoError(f"{path} is a folder, not an image")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise StereoGeoError(f"cannot read {path}: {exc.strerror or exc}") from None
    if not data:
        raise StereoGeoError(f"{path} is empty (0 bytes)")
    return data


def _truncation(data: bytes) -> str | None:
    """Why the file is cut short, or None when it is complete or of a format not checked here."""
    if data.startswith(_PNG_SIGNATURE):
        return _png_truncation(data)
    if data.startswith(b"\xff\xd8"):
        return _jpeg_truncation(data)
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        size = struct.unpack_from("<I", data, 4)[0] + 8
        return None if len(data) >= size else f"WebP of {len(data)} bytes, header says {size}"
    if data[:2] == b"BM" and len(data) >= 6:
        size = struct.unpack_from("<I", data, 2)[0]  # 0 in some writers: then unknown
        return None if len(data) >= size else f"BMP of {len(data)} bytes, header says {size}"
    return None  # TIFF and others: their decoders fail on missing data


def _png_truncation(data: bytes) -> str | None:
    # Walk the chunks (length, type, data, CRC) to IEND without decoding anything.
    pos = len(_PNG_SIGNATURE)
    while pos + 8 <= len(data):
        length, kind = struct.unpack_from(">I4s", data, pos)
        pos += 12 + length
        if kind == b"IEND":
            return None if pos <= len(data) else "PNG cut inside its IEND chunk"
    return "PNG without its IEND chunk"


def _jpeg_truncation(data: bytes) -> str | None:
    # Walk the marker segments to the first start-of-scan; the end-of-image marker must follow it.
    # Inside entropy-coded data a 0xFF byte is always followed by 0x00 or a restart marker, so FF D9
    # after the scan start is the real end (an EXIF thumbnail's FF D9 lies before it, inside APP1).
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            return None  # not a marker: leave it to the decoder
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker == 0xD9:
            return None
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:
            pos += 2
            continue
        if marker == 0xDA:
            return None if data.find(b"\xff\xd9", pos + 2) >= 0 else "JPEG without its end-of-image marker"
        pos += 2 + struct.unpack_from(">H", data, pos + 2)[0]
    return "JPEG cut before its image data"


def _to_uint8(image: np.ndarray, path: Path) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    if image.dtype == np.uint16:
        # round(v · 255 / 65535) in integers: 0 → 0, 65535 → 255
        return ((image.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
    if image.dtype in (np.float32, np.float64):
        return np.round(np.clip(np.nan_to_num(image), 0.0, 1.0) * 255.0).astype(np.uint8)
    raise StereoGeoError(f"cannot read {path}: unsupported pixel type {image.dtype} (use 8- or 16-bit)")
