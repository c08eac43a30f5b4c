"""write_calibration: golden files, formats, atomic writes, unwritable folders.

Regenerate the golden files (after a deliberate format change) with ``python tests/test_io_writers.py``.
"""

from __future__ import annotations

import dataclasses
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from stereogeo_cli.errors import EXIT_BAD_INPUT, StereoGeoError
from stereogeo_cli.geometry import gravity_from_roll_pitch, intrinsic_matrix, rotation_from_axis_angle
from stereogeo_cli.io import StereoCalibration, atomic, write_calibration

GOLDEN = Path(__file__).parent / "golden"
ALL_FILES = [
    "intrinsics.yml",
    "extrinsics.yml",
    "left.yaml",
    "right.yaml",
    "camchain.yaml",
    "cameras.txt",
    "report.json",
]
WRITTEN = [*ALL_FILES, "report.html"]  # every default format: the files above and the HTML report


def golden_rig() -> StereoCalibration:
    """A rig with everything set: distortion (k1..p2 left, k3 right), different image sizes, report data."""
    return StereoCalibration(
        K_left=intrinsic_matrix(500.0, 640, 480),
        K_right=np.array([[620.5, 0.0, 401.25], [0.0, 620.5, 299.75], [0.0, 0.0, 1.0]]),
        image_size_left=(640, 480),
        image_size_right=(800, 600),
        R=rotation_from_axis_angle([0.004, -0.03, 0.002]),
        T=np.array([-0.12, 0.001, -0.002]),
        D_left=np.array([-0.05, 0.012, 0.0004, -0.0003]),
        D_right=np.array([0.02, -0.01, 0.0, 0.0, 0.001]),
        gravity_left=gravity_from_roll_pitch(np.radians(2.0), np.radians(-5.0)),
        gravity_right=gravity_from_roll_pitch(np.radians(1.5), np.radians(-3.0)),
        sigma_left={"focal_px": 12.5, "vfov_deg": 1.1, "roll_deg": 0.2, "pitch_deg": 0.3},
        sigma_right={"focal_px": 15.0, "vfov_deg": 1.2, "roll_deg": 0.25, "pitch_deg": 0.35},
        scale_source="baseline",
        matches_found=812,
        matches_inliers=640,
        timing_ms={"total": 412.0, "network": 230.5, "refine": 11.25},
        model_file="models/stereogeo.onnx",
        model_sha256="0" * 64,
        notes="golden rig for tests",
    )


def test_golden_files_byte_for_byte(tmp_path):
    paths = write_calibration(tmp_path, golden_rig())
    # report.html, the last of the default formats, is a page of pictures: tests/test_report_html.py reads it
    assert [p.name for p in paths] == WRITTEN
    for name in ALL_FILES:
        assert (tmp_path / name).read_bytes() == (GOLDEN / name).read_bytes(), name


def test_formats_subset_and_order(tmp_path):
    paths = write_calibration(tmp_path, golden_rig(), formats=("json", "colmap", "json"))
    assert [p.name for p in paths] == ["report.json", "cameras.txt"]
    assert sorted(os.listdir(tmp_path)) == ["cameras.txt", "report.json"]


def test_unknown_format_writes_nothing(tmp_path):
    with pytest.raises(StereoGeoError, match="unknown output format 'matlab'") as err:
        write_calibration(tmp_path / "out", golden_rig(), formats=("opencv", "matlab"))
    assert err.value.exit_code == EXIT_BAD_INPUT
    assert not (tmp_path / "out").exists()


def test_creates_nested_folder(tmp_path):
    write_calibration(tmp_path / "a" / "b", golden_rig(), formats=("json",))
    assert (tmp_path / "a" / "b" / "report.json").is_file()


def _other_rig() -> StereoCalibration:
    return dataclasses.replace(golden_rig(), T=[-0.3, 0.0, 0.0])


def _assert_no_temporary_files(folder: Path) -> None:
    assert sorted(os.listdir(folder)) == sorted(WRITTEN)


def test_failing_write_leaves_previous_files_intact(tmp_path, monkeypatch):
    write_calibration(tmp_path, golden_rig())
    before = {name: (tmp_path / name).read_bytes() for name in ALL_FILES}
    calls = []

    def failing_fsync(fd):
        calls.append(fd)
        if len(calls) == 4:
            raise OSError(28, "No space left on device")

    monkeypatch.setattr(atomic.os, "fsync", failing_fsync)
    with pytest.raises(StereoGeoError, match="No space left on device") as err:
        write_calibration(tmp_path, _other_rig())
    assert err.value.exit_code == EXIT_BAD_INPUT
    assert {name: (tmp_path / name).read_bytes() for name in ALL_FILES} == before
    _assert_no_temporary_files(tmp_path)


def test_failing_rename_leaves_each_file_old_or_new(tmp_path, monkeypatch):
    write_calibration(tmp_path, golden_rig())
    old = {name: (tmp_path / name).read_bytes() for name in ALL_FILES}
    new_dir = tmp_path / "new"
    write_calibration(new_dir, _other_rig())
    new = {name: (new_dir / name).read_bytes() for name in ALL_FILES}
    real_replace, calls = os.replace, []

    def failing_replace(src, dst):
        calls.append(dst)
        if len(calls) == 3:
            raise OSError(5, "Input/output error")
        real_replace(src, dst)

    monkeypatch.setattr(atomic.os, "replace", failing_replace)
    with pytest.raises(StereoGeoError):
        write_calibration(tmp_path, _other_rig())
    now = {name: (tmp_path / name).read_bytes() for name in ALL_FILES}
    assert all(now[n] in (old[n], new[n]) for n in ALL_FILES)
    assert now["intrinsics.yml"] == new["intrinsics.yml"] and now["left.yaml"] == old["left.yaml"]
    assert sorted(os.listdir(tmp_path)) == sorted([*WRITTEN, "new"])


def test_interrupt_removes_temporary_files(tmp_path, monkeypatch):
    write_calibration(tmp_path, golden_rig())
    before = {name: (tmp_path / name).read_bytes() for name in ALL_FILES}

    def interrupt(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic.os, "fsync", interrupt)
    with pytest.raises(KeyboardInterrupt):
        write_calibration(tmp_path, _other_rig())
    assert {name: (tmp_path / name).read_bytes() for name in ALL_FILES} == before
    _assert_no_temporary_files(tmp_path)


def test_folder_that_cannot_be_made(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(StereoGeoError, match="cannot create output folder") as err:
        write_calibration(blocker / "out", golden_rig())
    assert err.value.exit_code == EXIT_BAD_INPUT
    assert "\n" not in str(err.value)
    with pytest.raises(StereoGeoError, match="is not a folder"):
        write_calibration(blocker, golden_rig())


def test_unwritable_folder_writes_nothing(tmp_path, monkeypatch):
    folder = tmp_path / "ro"
    folder.mkdir()
    if os.geteuid() != 0:  # root ignores permission bits: simulate the refusal instead
        folder.chmod(0o500)
    else:

        def refuse(*args, **kwargs):
            raise PermissionError(13, "Permission denied")

        monkeypatch.setattr(atomic.tempfile, "mkstemp", refuse)
    try:
        with pytest.raises(StereoGeoError, match="Permission denied") as err:
            write_calibration(folder, golden_rig())
    finally:
        folder.chmod(0o700)
    assert err.value.exit_code == EXIT_BAD_INPUT
    assert os.listdir(folder) == []


def test_folder_in_the_way_of_a_file(tmp_path):
    (tmp_path / "left.yaml").mkdir()
    with pytest.raises(StereoGeoError, match="left.yaml"):
        write_calibration(tmp_path, golden_rig())
    assert os.listdir(tmp_path) == ["left.yaml"]


def test_written_files_have_usual_permissions(tmp_path):
    umask = os.umask(0o022)
    try:
        (path,) = write_calibration(tmp_path, golden_rig(), formats=("json",))
    finally:
        os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o644


if __name__ == "__main__":
    written = write_calibration(GOLDEN, golden_rig(), formats=("opencv", "ros", "kalibr", "colmap", "json"))
    print("regenerated:", *written, sep="\n  ", file=sys.stderr)


def test_format_files_name_what_each_format_writes():
    from stereogeo_cli.io.writers import FORMAT_FILES, render_calibration

    for name, files in FORMAT_FILES.items():
        assert tuple(render_calibration(golden_rig(), (name,))) == files, name


def test_a_folder_is_replaced_whole_in_one_step(tmp_path):
    out = tmp_path / "out"
    old = {"report.json": "old", "left.yaml": "old", "sparse/0/points.bin": b"1"}
    atomic.replace_folder_atomically(out, old)
    written = atomic.replace_folder_atomically(out, {"report.json": "new", "sparse/0/cameras.bin": b"2"})
    assert written == [out / "report.json", out / "sparse/0/cameras.bin"]
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [
        "report.json", "sparse", "sparse/0", "sparse/0/cameras.bin"
    ]  # fmt: skip
    assert (out / "report.json").read_text() == "new"
    assert os.listdir(tmp_path) == ["out"]  # no staging or old folder left beside it
    assert (out.stat().st_mode & 0o777) == 0o777 & ~_umask()


def test_an_interrupted_folder_replacement_leaves_the_folder_as_it_was(tmp_path, monkeypatch):
    out = tmp_path / "out"
    atomic.replace_folder_atomically(out, {"report.json": "old", "left.yaml": "old"})

    def interrupt(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic.os, "fsync", interrupt)
    with pytest.raises(KeyboardInterrupt):
        atomic.replace_folder_atomically(out, {"report.json": "new"})
    assert {p.name: p.read_text() for p in out.iterdir()} == {"report.json": "old", "left.yaml": "old"}
    assert os.listdir(tmp_path) == ["out"]


def test_a_folder_replacement_without_an_exchange_goes_by_two_renames(tmp_path, monkeypatch):
    out = tmp_path / "out"
    atomic.replace_folder_atomically(out, {"a.txt": "old"})
    monkeypatch.setattr(atomic, "_exchange", lambda a, b: False)  # a system without renameat2
    atomic.replace_folder_atomically(out, {"b.txt": "new"})
    assert [p.name for p in out.iterdir()] == ["b.txt"]
    assert os.listdir(tmp_path) == ["out"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
