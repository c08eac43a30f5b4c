"""Which images of a folder form the pairs of ``batch-calibrate``, and the shards of a job array.

Pair discovery (:func:`discover_pairs`), in this order — the first layout present is the only one used:

1. ``FOLDER/left/`` and ``FOLDER/right/``: a pair is a left and a right image with the **same name
   stem** (``left/0001.png`` + ``right/0001.png``; the extensions may differ). ``make-data`` datasets and
   the evaluation sets (``calib.jsonl`` beside ``left/`` and ``right/``) have this layout.
2. ``FOLDER/cam0/`` (left) and ``FOLDER/cam1/`` (right), matched the same way; EuRoC/ASL's
   ``cam0/data/`` and ``cam1/data/`` are used when present.
3. Otherwise the images in ``FOLDER`` itself: ``<name>_left.<ext>`` + ``<name>_right.<ext>`` or
   ``<name>_L.<ext>`` + ``<name>_R.<ext>`` (suffixes in any letter case; the two styles may be mixed).

Everywhere: an image is a file whose extension, in any letter case, is one OpenCV decodes
(:data:`IMAGE_EXTENSIONS`); other files are ignored; folders are not searched recursively. The pair's name
is the stem (layouts 1, 2) or ``<name>`` (layout 3); its results go to ``OUT/<name>/``. A left image
without its right (or the reverse), two images of one side with the same name (``a.png`` and ``a.jpg``),
and in layout 3 an image without a side suffix, are each reported on one line and **count as failed
pairs**. A folder without a single pair is an error (exit code 2). Pairs are in natural sort order
(``img2`` before ``img10``), the same on every machine.

Sharding: ``--shard i/n`` (1-based: ``1/4`` … ``4/4``) takes the entries ``i-1, i-1+n, i-1+2n, …`` of that
sorted list, unmatched entries included, so the shards of a job array cover every entry exactly once.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.io.text import plural

IMAGE_EXTENSIONS = frozenset(
    ".png .jpg .jpeg .jpe .jp2 .tif .tiff .bmp .dib .webp .ppm .pgm .pbm .pnm .pxm .pfm .sr .ras .exr .hdr "
    ".pic".split()
)  # what cv2.imdecode reads (when OpenCV is built with the codec)
_SIDE_SUFFIX = re.compile(r"^(?P<name>.+)_(?P<side>left|right|l|r)$", re.IGNORECASE)


# ---------------------------------------------------------------------------------------------- discovery


@dataclass(frozen=True)
class PairEntry:
    """A discovered pair, or a name that could not be made into one (``problem`` says why)."""

    name: str
    left: Path | None
    right: Path | None
    problem: str | None = None


def _natural_key(name: str) -> tuple:
    return tuple(int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)), name


def _images(folder: Path) -> list[Path]:
    return [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()]


def _child_folder(folder: Path, name: str) -> Path | None:
    found = [p for p in folder.iterdir() if p.is_dir() and p.name.lower() == name]
    return sorted(found)[0] if found else None


def _match(groups: dict[str, dict[str, list[Path]]], labels: tuple[str, str]) -> list[PairEntry]:
    """Entries from ``{name: {"left": [paths], "right": [paths]}}``; labels name the sides in messages."""
    entries = []
    for name, sides in groups.items():
        left, right = sides.get("left", []), sides.get("right", [])
        for side_files, label in ((left, labels[0]), (right, labels[1])):
            if len(side_files) > 1:
                listed = ", ".join(p.name for p in sorted(side_files))
                entries.append(PairEntry(name, None, None, f"several {label} images named {name}: {listed}"))
                break
        else:
            if left and right:
                entries.append(PairEntry(name, left[0], right[0]))
            elif left:
                entries.append(PairEntry(name, left[0], None, f"{left[0].name} has no {labels[1]} image"))
            else:
                entries.append(PairEntry(name, None, right[0], f"{right[0].name} has no {labels[0]} image"))
    return entries


def discover_pairs(folder: str | os.PathLike) -> list[PairEntry]:
    """The pairs of ``folder`` (rules in the module docstring), in natural sort order of their names.

    Raises :class:`StereoGeoError` (exit code 2) for a missing folder or one without any pair.
    """
    folder = Path(folder)
    if not folder.exists():
        raise StereoGeoError(f"folder not found: {folder}")
    if not folder.is_dir():
        raise StereoGeoError(f"{folder} is not a folder")
    groups: dict[str, dict[str, list[Path]]] = {}
    entries: list[PairEntry] = []
    for left_name, right_name in (("left", "right"), ("cam0", "cam1")):
        left_dir, right_dir = _child_folder(folder, left_name), _child_folder(folder, right_name)
        if left_dir is None and right_dir is None:
            continue
        if left_dir is None or right_dir is None:
            have, missing = (left_name, right_name) if right_dir is None else (right_name, left_name)
            raise StereoGeoError(f"{folder} has a {have}/ folder but no {missing}/ folder")
        labels = (left_dir.name + "/", right_dir.name + "/")
        for side, side_dir in (("left", left_dir), ("right", right_dir)):
            if (side_dir / "data").is_dir() and not _images(side_dir):  # EuRoC / ASL: cam0/data/*.png
                side_dir = side_dir / "data"
            for path in _images(side_dir):
                groups.setdefault(path.stem, {}).setdefault(side, []).append(path)
        entries = _match(groups, labels)
        layout = f"a left image in {labels[0]} and a right image of the same name in {labels[1]}"
        break
    else:
        layout = (
            "left/ + right/ or cam0/ + cam1/ folders of images with the same names, or <name>_left + "
            "<name>_right (or <name>_L + <name>_R) image files in the folder itself"
        )
        for path in _images(folder):
            m = _SIDE_SUFFIX.match(path.stem)
            if m is None:
                problem = f"{path.name} is not part of a pair: its name must end in _left, _right, _L or _R"
                entries.append(PairEntry(path.stem, None, None, problem))
                continue
            side = "left" if m["side"].lower() in ("left", "l") else "right"
            groups.setdefault(m["name"], {}).setdefault(side, []).append(path)
        entries += _match(groups, ("left", "right"))
    if not any(e.problem is None for e in entries):
        found = f" ({plural(len(entries), 'unmatched image')})" if entries else ""
        raise StereoGeoError(f"no stereo pairs in {folder}{found}; expected {layout}")
    return sorted(entries, key=lambda e: _natural_key(e.name))


def parse_shard(text: str) -> tuple[int, int]:
    """``"i/n"`` → (i, n), 1-based (1 ≤ i ≤ n); anything else raises :class:`StereoGeoError` (exit code 2)."""
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text)
    if m is None:
        raise StereoGeoError(f"--shard must look like i/n (e.g. 1/4), got {text!r}")
    i, n = int(m[1]), int(m[2])
    if n < 1 or not 1 <= i <= n:
        hint = " (shards are numbered from 1)" if i == 0 else ""
        raise StereoGeoError(f"--shard {text}: i must be between 1 and n, and n at least 1{hint}")
    return i, n


def select_shard(entries: Sequence[PairEntry], shard: tuple[int, int] | None) -> list[PairEntry]:
    """Every n-th entry starting at entry i-1 for ``shard = (i, n)``; all entries for None."""
    if shard is None:
        return list(entries)
    i, n = shard
    return list(entries[i - 1 :: n])


# ------------------------------------------------------------------------------------------ per-pair work
