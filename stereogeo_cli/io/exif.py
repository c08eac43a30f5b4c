"""The focal length a photo's EXIF metadata records, in pixels of the image as loaded.

Phones and cameras write the lens's focal length into EXIF; COLMAP and other structure-from-motion tools
start from it. ``calibrate`` takes it as a prior on each camera's focal length (``--no-exif`` turns that
off), weighed against what the network's fields read: the two are combined by their 1-sigma figures.

Two routes, the first that applies:

- ``FocalLengthIn35mmFilm`` (tag 0xA405): the 35 mm-equivalent focal length F35, which CIPA DC-008 scales
  by the diagonal, so ``f = F35 · hypot(w, h) / hypot(36, 24)`` pixels. It is rounded to whole millimetres
  (2 % at 26 mm) and some makers scale by the width instead (4 % apart for 4:3 frames): 1-sigma 5 %.
- ``FocalLength`` (0x920A) with ``FocalPlaneXResolution`` and its unit (0xA20E, 0xA210): the focal length in
  millimetres times the sensor's pixels per millimetre, scaled to the image's width when it was resized.
  Makers fill the focal-plane resolution less consistently: 1-sigma 8 %.

A photo that was cropped does not have the focal length its tags describe in these terms. Where EXIF
records the original pixel size (``PixelXDimension``, ``PixelYDimension``) and its shape differs from the
file's, the tags are not used and the reason is returned. A resize keeps the shape and is fine. A crop that
keeps the shape, or a digital zoom whose tags were not updated, cannot be seen here: ``calibrate`` warns
when the fields disagree strongly.

Orientation: the tags describe the stored sensor grid; ``load_image`` applies the EXIF orientation, so
for orientations 5–8 the image as loaded is the stored one turned by 90°. Its diagonal is the same.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from stereogeo_cli.geometry.camera import vfov_from_focal
from stereogeo_cli.refine.lm import default_conf as refine_conf

SIGMA_35MM = 0.05  # relative 1-sigma of a focal length from FocalLengthIn35mmFilm (module docstring)
SIGMA_FOCAL_PLANE = 0.08  # ... and from FocalLength with FocalPlaneXResolution
MAX_SHAPE_CHANGE = 0.01  # |log| of the aspect ratio change beyond which the photo counts as cropped
DIAGONAL_35MM = math.hypot(36.0, 24.0)  # millimetres: the frame FocalLengthIn35mmFilm refers to

_EXIF_IFD = 0x8769
_ORIENTATION = 0x0112
_FOCAL_35MM = 0xA405
_FOCAL_LENGTH = 0x920A
_PLANE_X_RESOLUTION = 0xA20E
_PLANE_UNIT = 0xA210
_PIXEL_X, _PIXEL_Y = 0xA002, 0xA003
# FocalPlaneResolutionUnit in millimetres: inch, cm (the standard's), and mm, µm (some writers')
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 1e-3}


@dataclass(frozen=True)
class FocalPrior:
    """A prior on a focal length, in pixels of the image as loaded (EXIF orientation applied): read from
    EXIF, or given by the caller with a sigma."""

    focal_px: float
    sigma_rel: float  # relative 1-sigma
    tag: str  # "FocalLengthIn35mmFilm" or "FocalLength" ("given" for a given one)
    value_mm: float | None  # the tag's value in millimetres (35 mm-equivalent for the first); None if given
    # "exif"; "given" for a focal length the caller gave with a sigma (pipeline conf known_focal_sigma)
    source: str = "exif"

    @property
    def sigma_px(self) -> float:
        return self.focal_px * self.sigma_rel


def read_exif_focal(path: str | os.PathLike, width: int, height: int) -> tuple[FocalPrior | None, str | None]:
    """The focal length the EXIF of ``path`` records, for the image as loaded (``width`` x ``height``).

    Returns ``(focal, None)``, or ``(None, reason)`` when EXIF has focal tags that cannot be used (a cropped
    photo, a value out of range), or ``(None, None)`` when it has none (most PNGs; any file Pillow cannot
    read). Never raises: EXIF is optional metadata, and a damaged block is the same as none.
    """
    try:
        tags, exif = _read_tags(path)
    except Exception:  # noqa: BLE001 - unreadable or damaged metadata: as if there were none
        return None, None
    if tags is None:
        return None, None
    focal_35mm = _number(exif.get(_FOCAL_35MM))
    focal_mm = _number(exif.get(_FOCAL_LENGTH))
    plane_resolution = _number(exif.get(_PLANE_X_RESOLUTION))
    unit = _UNIT_MM.get(int(_number(exif.get(_PLANE_UNIT)) or 2))
    usable_35mm = focal_35mm is not None and focal_35mm > 0
    usable_plane = focal_mm is not None and focal_mm > 0 and plane_resolution and unit is not None
    if not (usable_35mm or usable_plane):
        return None, None

    name = os.fspath(path)
    turned = int(_number(tags.get(_ORIENTATION)) or 1) in (5, 6, 7, 8)
    stored_w, stored_h = (height, width) if turned else (width, height)
    original_w, original_h = _number(exif.get(_PIXEL_X)), _number(exif.get(_PIXEL_Y))
    if original_w and original_h:
        change = abs(math.log((original_w / original_h) / (stored_w / stored_h)))
        if change > MAX_SHAPE_CHANGE:
            return None, (
                f"{name}: EXIF focal length not used, the photo was cropped (EXIF size "
                f"{original_w:.0f}x{original_h:.0f}, image {stored_w}x{stored_h})"
            )
    if usable_35mm:
        found = FocalPrior(
            focal_35mm * math.hypot(width, height) / DIAGONAL_35MM,
            SIGMA_35MM, "FocalLengthIn35mmFilm", float(focal_35mm),
        )  # fmt: skip
    else:
        resized = stored_w / original_w if original_w else 1.0
        found = FocalPrior(
            focal_mm * plane_resolution / unit * resized, SIGMA_FOCAL_PLANE, "FocalLength", float(focal_mm)
        )
    vfov = math.degrees(float(vfov_from_focal(found.focal_px, height)))
    if not refine_conf["min_vfov_deg"] <= vfov <= refine_conf["max_vfov_deg"]:  # outside the refiner's range
        return None, f"{name}: EXIF focal length not used, {found.tag} gives a vFoV of {vfov:.1f}°"
    return found, None


def _read_tags(path):
    """(IFD0 tags, Exif IFD tags) of a file, or (None, None) when it has no EXIF."""
    with open(path, "rb") as file:
        png = file.read(len(_PNG_SIGNATURE)) == _PNG_SIGNATURE
        block = _png_exif_chunk(file) if png else None
    if png and block is None:  # most PNGs: no EXIF, and no need to load Pillow to say so
        return None, None
    from PIL import Image

    if png:  # Pillow decodes a PNG's pixels to look for EXIF after them; its chunk list says where it is
        tags = Image.Exif()
        tags.load(block)
        return (dict(tags), dict(tags.get_ifd(_EXIF_IFD))) if tags else (None, None)
    # Only the header is read, never the pixels, so Pillow's guard against decompression bombs (a warning
    # from 89 MP, an error from 179 MP: a 200 MP phone photo) does not apply here.
    limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
    try:
        with Image.open(path) as image:
            tags = image.getexif()
            if not tags:
                return None, None
            return dict(tags), dict(tags.get_ifd(_EXIF_IFD))
    finally:
        Image.MAX_IMAGE_PIXELS = limit


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_exif_chunk(file) -> bytes | None:
    """The data of a PNG's ``eXIf`` chunk (TIFF-format EXIF), or None: the chunks' headers are read and
    their data skipped, up to ``IEND`` (``file`` positioned after the signature)."""
    while header := file.read(8):
        if len(header) < 8:
            return None
        length, kind = int.from_bytes(header[:4], "big"), header[4:]
        if kind == b"eXIf":
            return file.read(length)
        if kind == b"IEND":
            return None
        file.seek(length + 4, 1)  # the data and its CRC
    return None


def _number(value) -> float | None:
    """A tag's value as a float (rationals included), or None; a tuple (some writers) gives its first."""
    if isinstance(value, tuple | list):
        value = value[0] if value else None
    try:
        number = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return number if math.isfinite(number) else None


def exif_focals(paths, images) -> tuple[tuple[FocalPrior | None, str | None], ...]:
    """:func:`read_exif_focal` of each file of a pair, for its image as loaded ([H x W x 3])."""
    return tuple(
        read_exif_focal(path, image.shape[1], image.shape[0])
        for path, image in zip(paths, images, strict=True)
    )
