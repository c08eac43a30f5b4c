"""``stereogeo calibrate-sequence`` as a user runs it: rendered sequences with exact ground truth, the files
it writes read back by their readers, bad sources, and an interrupted run."""

from __future__ import annotations

import json
import math
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from stereogeo_cli.geometry import rotation_angle

pytestmark = pytest.mark.slow


def _render(folder: Path, motion: str, frames: int, seed: int) -> Path:
    pytest.importorskip("moderngl")
    from stereogeo_cli.synth.sequence import make_sequence, sequence_config

    # 320 x 240 in a room (texture on every side), as small as COLMAP still matches well
    make_sequence(
        folder, motion, frames, seed, sequence_config(short_side=240, outdoor_share=0.0), progress=False
    )
    return folder


def _stereogeo(*args, check=True, timeout=900) -> subprocess.CompletedProcess:
    env = {**os.environ, "COLUMNS": "120"}
    done = subprocess.run(
        [sys.executable, "-m", "stereogeo_cli", *map(str, args)], capture_output=True, text=True,
        timeout=timeout, env=env,
    )  # fmt: skip
    if check and done.returncode != 0:
        raise AssertionError(f"exit {done.returncode}: {done.stderr}")
    return done


@pytest.fixture(scope="module")
def turning(tmp_path_factory) -> tuple[Path, dict, Path, dict]:
    """A rig turning in a room (16 frames at 320 x 240), calibrated once: (sequence, its ground truth,
    output folder, report)."""
    folder = _render(tmp_path_factory.mktemp("turning") / "seq", "turning", 16, 7)
    out = folder.parent / "out"
    done = _stereogeo("calibrate-sequence", folder, "-o", out, "--json")
    return folder, json.loads((folder / "calib.json").read_text()), out, json.loads(done.stdout)


def test_a_turning_rig_gets_its_focal_length_r_and_t_from_the_sequence(turning):
    _, truth, _, report = turning
    seq = report["sequence"]
    assert seq["frames_registered"] == seq["frames_read"] == 16
    assert seq["focal_observable"] is True
    assert seq["rotation_span_deg"] > 30
    for side in ("left", "right"):
        f_true = truth[side]["K"][0][0]
        error = report[side]["focal_px"] / f_true - 1
        # the pairs alone read renders to ~3 %; the adjustment of 16 frames to well under 1 %
        assert abs(error) < 0.015, (side, error)
        assert abs(error) * f_true < 3 * report[side]["sigma"]["focal_px"]
    R_error = math.degrees(rotation_angle(np.array(report["R"]) @ np.array(truth["R"]).T))
    assert R_error < 0.15
    T, T_true = np.array(report["T"]), np.array(truth["T"])
    assert math.degrees(math.acos(T @ T_true / np.linalg.norm(T) / np.linalg.norm(T_true))) < 1.0
    assert R_error < 3 * report["pose"]["sigma_rotation_deg"]


def test_frames_left_out_of_the_fit_line_up_once_rectified(turning):
    """The check a stereo calibration is judged by: each stretch of frames, left out of the adjustment,
    rectified with the calibration fitted without it; a render's rows meet well under ROS's 0.25 px."""
    _, _, _, report = turning
    left_out = report["sequence"]["left_out"]
    assert left_out["blocks"] == 5 and len(left_out["focal_px"]) == 5
    rows = left_out["row_error_px"]
    assert rows["matches"] > 1000
    assert rows["median"] < 0.25 and rows["median"] <= rows["p95"] < 1.0
    # the adjustment's focal sigma is at least what the stretches' spread says
    for side in ("left", "right"):
        adjusted = report["sequence"]["evidence"]["focal"][side]["adjustment"]
        assert adjusted["sigma_px"] >= left_out["focal_sigma_rel"] * adjusted["focal_px"]
    assert report["pose"]["sigma_rotation_deg"] >= left_out["rotation_sigma_deg"]


def test_a_render_reads_alike_in_least_squares_and_with_a_robust_loss(turning):
    """Where the camera model and a still scene fit the frames, weighing the residuals robustly moves the
    adjustment by far less than its sigma; the parting is part of the reported sigmas all the same."""
    _, _, _, report = turning
    robust = report["sequence"]["robust"]
    assert robust["focal_rel"] < 0.005 and robust["rotation_deg"] < 0.05
    for side in ("left", "right"):
        adjusted = report["sequence"]["evidence"]["focal"][side]["adjustment"]
        assert adjusted["sigma_px"] >= robust["focal_rel"] * adjusted["focal_px"]
    assert report["pose"]["sigma_rotation_deg"] >= robust["rotation_deg"]


def test_a_render_reads_alike_with_its_principal_points_freed_under_a_prior(turning):
    """A render's principal points lie exactly at the image centre: freeing them under a prior leaves them
    within a pixel or two of it and moves the adjustment by far less than its sigma; the parting is part of
    the reported sigmas all the same."""
    _, truth, _, report = turning
    reading = report["sequence"]["principal_point_reading"]
    assert reading["focal_rel"] < 0.005 and reading["rotation_deg"] < 0.05
    for side in ("left", "right"):
        width, height = truth[side]["width"], truth[side]["height"]
        np.testing.assert_allclose(reading["principal_point_px"][side], [width / 2, height / 2], atol=2.0)
        adjusted = report["sequence"]["evidence"]["focal"][side]["adjustment"]
        assert adjusted["sigma_px"] >= reading["focal_rel"] * adjusted["focal_px"]
    assert report["pose"]["sigma_rotation_deg"] >= reading["rotation_deg"]


def test_the_principal_point_prior_pulls_as_hard_as_its_sigma_says(turning):
    """From principal points 10 and 6 px off the centre: an adjustment that holds them keeps them there; one
    under a prior of a tiny sigma brings them to the image centre; under a prior of a sigma as wide as the
    image it leaves them where the adjustment that frees them without a prior puts them (the frames fix
    them to a fraction of a pixel)."""
    pycolmap = pytest.importorskip("pycolmap")
    from stereogeo_cli.sequence import colmap

    _, _, out, _ = turning

    def adjusted(free: bool = False, share: float | None = None) -> np.ndarray:
        model = pycolmap.Reconstruction(out / "sparse" / "0")
        for camera in model.cameras.values():
            params = np.array(camera.params)
            params[list(camera.principal_point_idxs())] += [10.0, -6.0]
            camera.params = params
        prior = None if share is None else colmap.CentrePrior(0.3, share)
        colmap._bundle_adjust(model, False, True, refine_principal_point=free, centre_prior=prior)
        return np.array([
            [c.principal_point_x - c.width / 2 - 0.5, c.principal_point_y - c.height / 2 - 0.5]
            for c in model.cameras.values()
        ])  # fmt: skip

    np.testing.assert_allclose(adjusted(), [[10.0, -6.0]] * 2, atol=1e-9)
    np.testing.assert_allclose(adjusted(share=1e-6), 0.0, atol=0.01)
    free = adjusted(free=True)
    assert np.all(np.abs(free) < 2.0)
    np.testing.assert_allclose(adjusted(share=1.0), free, atol=0.01)


def test_each_frame_gets_its_roll_and_pitch_in_a_world_with_z_up(turning):
    folder, truth, _, report = turning
    up = np.array(truth["gravity_up_world"])
    errors = []
    for frame in report["sequence"]["frames"]:
        g = np.array(truth["gt_poses"][frame["index"]])[:3, :3].T @ up
        errors.append(math.degrees(math.acos(np.clip(g @ np.array(frame["left"]["gravity_up"]), -1, 1))))
    # one world up from 32 readings (the network's, about 1° each at 320 x 240), within its sigma: the
    # frames' gravity errs as that one up does, the poses add nothing
    sigma = report["sequence"]["world"]["sigma_up_deg"]
    assert np.ptp(errors) < 0.2
    assert np.median(errors) < min(3 * sigma, 2.5)


def test_the_files_load_in_their_readers(turning):
    pycolmap = pytest.importorskip("pycolmap")
    import cv2

    _, _, out, report = turning
    assert json.loads((out / "report.json").read_text()) == report
    fs = cv2.FileStorage(str(out / "intrinsics.yml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_allclose(fs.getNode("M1").mat(), report["left"]["K"])
    model = pycolmap.Reconstruction(out / "sparse" / "0")
    assert model.num_reg_frames() == report["sequence"]["frames_registered"]
    lines = [line for line in (out / "trajectory.txt").read_text().splitlines() if not line.startswith("#")]
    assert len(lines) == report["sequence"]["frames_registered"]
    stamps = [float(line.split()[0]) for line in lines]
    assert stamps == sorted(stamps)
    first = np.array(lines[0].split()[1:4], dtype=float)
    np.testing.assert_allclose(first, 0.0, atol=1e-9)  # the world starts at the first left camera


def test_a_rig_mounted_upside_down_gets_its_gravity_with_rotate_180(tmp_path, turning):
    """The turning rig turned 180° about its view, its cameras keeping their names (each sees the other's
    view turned): without --rotate every frame's gravity comes out reversed; with it, as upright."""
    import cv2

    folder, truth, _, upright = turning
    turned = tmp_path / "turned"
    for side, other in (("left", "right"), ("right", "left")):
        (turned / side).mkdir(parents=True)
        for path in sorted((folder / other).iterdir()):
            cv2.imwrite(
                str(turned / side / path.name), cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[::-1, ::-1]
            )
    up, R = np.array(truth["gravity_up_world"]), np.array(truth["R"])
    flip = np.diag([-1.0, -1.0, 1.0])  # the named left camera's frame is the right camera's turned

    def errors(report):
        out = []
        for frame in report["sequence"]["frames"]:
            g = flip @ R @ np.array(truth["gt_poses"][frame["index"]])[:3, :3].T @ up
            out.append(math.degrees(math.acos(np.clip(g @ np.array(frame["left"]["gravity_up"]), -1, 1))))
        return np.array(out)

    plain = json.loads(_stereogeo("calibrate-sequence", turned, "--json", "--no-progress").stdout)
    assert np.median(errors(plain)) > 170
    report = json.loads(
        _stereogeo("calibrate-sequence", turned, "--json", "--no-progress", "--rotate", "180").stdout
    )
    assert report["sequence"]["frames_registered"] == 16 and report["rotate_deg"] == 180
    assert np.median(errors(report)) < min(3 * report["sequence"]["world"]["sigma_up_deg"], 2.5)
    assert report["left"]["focal_px"] == pytest.approx(upright["right"]["focal_px"], rel=0.015)
    T_upright = flip @ (-np.array(upright["R"]).T @ np.array(upright["T"]))
    assert (
        np.degrees(
            np.arccos(T_upright @ report["T"] / np.linalg.norm(T_upright) / np.linalg.norm(report["T"]))
        )
        < 1
    )


def test_a_static_rig_is_calibrated_from_its_pairs_and_says_so(tmp_path):
    folder = _render(tmp_path / "seq", "static", 4, 7)
    done = _stereogeo("calibrate-sequence", folder, "--json", check=False)
    assert "Traceback" not in done.stderr
    if done.returncode == 3:  # nothing to reconstruct from: one line saying why
        assert len(done.stderr.strip().splitlines()) == 1
        return
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["sequence"]["focal_observable"] is False
    truth = json.loads((folder / "calib.json").read_text())
    f_true = truth["left"]["K"][0][0]
    assert abs(report["left"]["focal_px"] - f_true) < 3 * report["left"]["sigma"]["focal_px"]


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["missing-folder"], "missing-folder"),
        (["--sbs", "broken.mp4"], "broken.mp4"),
    ],
)
def test_a_bad_source_is_one_line_and_exit_2(tmp_path, args, words):
    (tmp_path / "broken.mp4").write_bytes(os.urandom(4096))
    done = subprocess.run(
        [sys.executable, "-m", "stereogeo_cli", "calibrate-sequence", *args, "-o", "out"], cwd=tmp_path,
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0]
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_an_interrupted_sequence_writes_nothing_and_exits_130(tmp_path, turning):
    folder = turning[0]
    out = tmp_path / "out"
    process = subprocess.Popen(
        [sys.executable, "-m", "stereogeo_cli", "calibrate-sequence", folder, "-o", out, "--no-progress"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    time.sleep(6)  # the network is loaded and frames are being read
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=300)
    assert process.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert "nothing was written" in stderr
    assert not out.exists() or not any(out.rglob("*"))


def test_a_side_by_side_video_calibrates_as_its_frames_do(tmp_path, turning):
    """The turning sequence as one lossless side-by-side video: the same rig from the video's frames."""
    import cv2
    from test_sequence_sources import write_video

    folder, truth, _, report = turning
    frames = []
    for name in sorted(p.name for p in (folder / "left").iterdir()):
        left, right = (cv2.imread(str(folder / side / name))[..., ::-1] for side in ("left", "right"))
        frames.append(np.concatenate([left, right], axis=1))
    write_video(tmp_path / "sbs.mkv", frames, "FFV1", fps=8)
    done = _stereogeo("calibrate-sequence", "--sbs", tmp_path / "sbs.mkv", "--json")
    from_video = json.loads(done.stdout)
    assert from_video["sequence"]["frames_read"] == 16
    assert from_video["sequence"]["frames"][1]["time"] == pytest.approx(1 / 8)
    for side in ("left", "right"):
        assert from_video[side]["focal_px"] == pytest.approx(truth[side]["K"][0][0], rel=0.015)


def test_a_bag_without_the_topic_is_one_line_and_exit_2(tmp_path):
    from test_sequence_sources import ROS1, image_msg, write_bag

    store = ROS1
    image = np.zeros((80, 96), np.uint8)
    write_bag(tmp_path / "run.bag", {"/cam0/image_raw": [image_msg(store, 10**9, image, "mono8")]})
    done = subprocess.run(
        [sys.executable, "-m", "stereogeo_cli", "calibrate-sequence", "run.bag", "--left-topic",
         "/cam0/image_raw", "--right-topic", "/cam1/image_raw", "-o", "out"], cwd=tmp_path,
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "/cam1/image_raw" in lines[0]
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------ signals, reruns, progress

# a stage's log line on stderr where it is no terminal: "COLMAP: mapping: 3.4 s", "reading …, 5 of 16: …"
STAGE_LINE = re.compile(
    r"^[^:]+(: [^:]+)?(, \d+ of \d+)?: (stopped after )?\d+\.\d s(; about [^;]+ left in all)?$"
)  # and the whole run's time left, where it is known


class _Running:
    """``calibrate-sequence`` running in the background, its stderr read line by line as it comes."""

    def __init__(self, *args, env=None):
        self.process = subprocess.Popen(
            [sys.executable, "-m", "stereogeo_cli", "calibrate-sequence", *map(str, args)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
        )  # fmt: skip
        self.lines: queue.Queue = queue.Queue()
        self.stderr: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.process.stderr:
            self.lines.put(line)
        self.lines.put(None)

    def wait_for(self, start: str, timeout: float = 240) -> None:
        """Wait until a line of stderr starts with ``start`` (a stage that ended)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=1)
            except queue.Empty:
                continue
            if line is None:
                break
            self.stderr.append(line.rstrip("\n"))
            if line.startswith(start):
                return
        raise AssertionError(f"no line {start!r} on stderr: {self.stderr}")

    def finish(self, timeout: float = 240) -> tuple[int, list[str]]:
        self.process.wait(timeout=timeout)
        while (line := self.lines.get(timeout=10)) is not None:
            self.stderr.append(line.rstrip("\n"))
        return self.process.returncode, self.stderr


@pytest.mark.parametrize(
    "moment",
    [
        "while Python starts",
        "while frames are read",  # after the network is loaded
        "inside COLMAP",  # its matching, after every frame is read
    ],
)
def test_sigterm_at_any_moment_exits_143_with_one_line_and_leaves_nothing(tmp_path, turning, moment):
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    out = tmp_path / "out"
    running = _Running(turning[0], "-o", out, env={**os.environ, "TMPDIR": str(temporary)})
    if moment == "while Python starts":
        time.sleep(0.5)  # its handler is in place within about 0.1 s: the libraries are loading
    else:
        running.wait_for("loading the network" if moment == "while frames are read" else "reading")
        time.sleep(1.0)
    running.process.send_signal(signal.SIGTERM)
    code, stderr = running.finish()
    assert code == 143, stderr
    *stages, last = stderr
    assert last.startswith("error: interrupted by SIGTERM"), stderr
    assert all(STAGE_LINE.match(line) for line in stages), stderr  # no stack, native or Python's
    if moment == "inside COLMAP":
        assert stages[-1].startswith("COLMAP: matching the frames: stopped after"), stderr
    assert not out.exists()
    assert not [p.name for p in temporary.iterdir() if p.name.startswith("stereogeo")]


def test_a_rerun_into_a_used_folder_is_refused_and_overwrite_replaces_it_whole(tmp_path, turning):
    folder, _, first, _ = turning
    out = tmp_path / "out"
    shutil.copytree(first, out)
    before = sorted(str(p.relative_to(out)) for p in out.rglob("*"))
    assert "left.yaml" in before and "trajectory.txt" in before
    done = _stereogeo("calibrate-sequence", folder, "-o", out, "--format", "json", check=False)
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert str(out) in line and "--overwrite" in line
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == before

    done = _stereogeo("calibrate-sequence", folder, "-o", out, "--format", "json", "--overwrite")
    assert sorted(p.name for p in out.iterdir()) == ["report.json", "sparse", "trajectory.txt"]
    assert os.listdir(tmp_path) == ["out"]  # no staging or old folder beside it
    report = json.loads((out / "report.json").read_text())
    assert report["sequence"]["frames_registered"] == 16
    # without a terminal, each stage is one log line on stderr as it ends, with its time
    stages = [line for line in done.stderr.splitlines() if STAGE_LINE.match(line)]
    first = [
        "opening the source", "choosing keyframes by motion, 16 of 16 (16 of 16 kept)", "loading the network",
        "reading and calibrating frame pairs, 16 of 16",
    ]  # fmt: skip
    assert [s.split(":")[0] for s in stages][:4] == first
    assert any(s.startswith("COLMAP: mapping (16 of 16 frames registered): ") for s in stages)
    assert any(s.startswith("writing the results: ") for s in stages)
    # the time left follows each stage from the reading of the frames on, the last one aside
    assert all("left in all" in s for s in stages[3:-2]), stages

    (out / "notes.txt").write_text("mine")  # not a sequence's: --overwrite does not delete it
    done = _stereogeo("calibrate-sequence", folder, "-o", out, "--overwrite", check=False)
    assert done.returncode == 2 and "notes.txt" in done.stderr
    assert (out / "notes.txt").read_text() == "mine"


def test_warnings_go_to_stderr_and_the_summary_to_stdout(tmp_path):
    folder = _render(tmp_path / "seq", "static", 4, 7)
    done = _stereogeo("calibrate-sequence", folder, "-o", tmp_path / "out", check=False)
    assert done.returncode in (0, 3), done.stderr
    if done.returncode == 3:  # nothing to reconstruct from: one line saying why
        return
    assert "warning:" in done.stderr and "the motion does not fix the focal length" in done.stderr
    assert "warning:" not in done.stdout and "focal" in done.stdout


def _quick(tmp_path, *args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "stereogeo_cli", *map(str, args)], cwd=tmp_path, capture_output=True,
        text=True, timeout=300,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["calibrate-sequence", ".", "--every", "0"], "--every must be at least 1"),
        (["calibrate-sequence", ".", "--fps", "nan"], "--fps must be a positive number"),
        (["calibrate-sequence", ".", "--max-frames", "0"], "--max-frames must be at least 1"),
        (["calibrate-sequence", ".", "--stamp-tolerance", "-1"], "--stamp-tolerance must be 0 s or more"),
        (["calibrate-sequence", ".", "--stamp-tolerance", "0.05"], "--stamp-tolerance is for bags only"),
        (["calibrate-sequence", ".", "--workspace", "file.txt"], "--workspace file.txt is a file"),
        (["calibrate-sequence", ".", "--bogus"], "No such option: --bogus"),
        (["calibrate"], "Missing argument"),
    ],
)
def test_a_usage_error_is_one_line_and_exit_2(tmp_path, args, words):
    (tmp_path / "file.txt").write_text("not a folder")
    done = _quick(tmp_path, *args)
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert line.startswith("error: ") and words in line, line
    assert done.stdout == ""


def test_a_bag_of_free_running_cameras_pairs_with_a_wider_stamp_tolerance(tmp_path):
    from test_sequence_sources import ROS1, T0, image_msg, noise, write_bag

    step, offset = 100_000_000, 30_000_000  # 10 Hz, the right camera 30 ms after the left
    left = [image_msg(ROS1, T0 + i * step, noise(64, 80, i), "rgb8") for i in range(2)]
    right = [image_msg(ROS1, T0 + i * step + offset, noise(64, 80, 9 + i), "rgb8") for i in range(2)]
    write_bag(tmp_path / "run.bag", {"/left": left, "/right": right})
    topics = ["--left-topic", "/left", "--right-topic", "/right"]
    done = _quick(tmp_path, "calibrate-sequence", "run.bag", *topics, "--no-progress")
    assert done.returncode == 2
    (line,) = done.stderr.strip().splitlines()
    assert "within 0.01 s" in line and "--stamp-tolerance" in line
    # paired within 50 ms: one pair read (of --max-frames 1) is then too few for a sequence
    done = _quick(tmp_path, "calibrate-sequence", "run.bag", *topics, "--stamp-tolerance", "0.05",
                  "--max-frames", "1", "--no-progress")  # fmt: skip
    assert done.returncode == 2
    assert "a sequence needs 2 frame pairs or more (1 read)" in done.stderr.strip().splitlines()[-1]


def test_help_into_a_closed_pipe_is_no_traceback(tmp_path):
    """``stereogeo calibrate-sequence --help | head -1``: the reader goes away; nothing is said of it."""
    process = subprocess.Popen(
        [sys.executable, "-m", "stereogeo_cli", "calibrate-sequence", "--help"], cwd=tmp_path,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "COLUMNS": "80"},
    )  # fmt: skip
    process.stdout.close()  # the reader is gone before the help is written
    stderr = process.communicate(timeout=300)[1]
    assert "Traceback" not in stderr and process.returncode in (0, 1), stderr


def test_a_stage_line_fits_a_narrow_terminal_and_each_stage_shows_its_time(capsys):
    """On a terminal: the stage's name is cut short before its bar, count and times are pushed off the line
    (a long source path once did that); without one: one log line per stage, with its count and time."""
    import io

    from rich.console import Console

    from stereogeo_cli.jobs import progress as progress_module

    screen = io.StringIO()
    bar = progress_module.StageProgress(
        "bar", Console(file=screen, force_terminal=True, width=60, color_system=None)
    )
    with bar:
        bar(0, 16, "reading frames of /a/very/long/path/to/a/recording/that/goes/on/and/on/seq")
        bar(16, 16)
        bar(0, None, "COLMAP: mapping")
    last = screen.getvalue().split("\x1b[2K")[-1]
    lines = [line for line in last.replace("\r", "\n").split("\n") if line.strip() and "\x1b" not in line]
    assert lines and all(len(line) <= 60 for line in lines), lines
    assert any("16/16" in line for line in lines)

    log = progress_module.StageProgress("log")
    with log:
        log(0, 3, "reading frames")
        log(3, 3)
        log(0, None, "COLMAP: mapping")
    err = capsys.readouterr().err.splitlines()
    assert [STAGE_LINE.match(line) is not None for line in err] == [True, True]
    assert err[0].startswith("reading frames, 3 of 3: ") and err[1].startswith("COLMAP: mapping: ")


def test_the_time_left_follows_the_pace_of_the_stages_done(monkeypatch, capsys):
    """The whole run's time left: the stages to come as expected, scaled by how the stages done went (here
    1.6 times slower than expected), less what the stage in flight has run; each log line ends with it."""
    from stereogeo_cli.jobs import progress as progress_module

    now = [0.0]
    monkeypatch.setattr(progress_module.time, "perf_counter", lambda: now[0])
    log = progress_module.StageProgress("log")
    with log:
        log.expect({"reading": 10.0, "mapping": 30.0, "adjusting": 20.0})
        assert log.time_left() == 60.0  # nothing done yet: as expected
        log(0, 4, "reading")
        now[0] = 16.0  # the reading took 1.6 times as long as expected
        log(4, 4)
        log(0, None, "mapping")
        assert log.time_left() == pytest.approx(1.6 * (30.0 + 20.0))
        now[0] = 40.0  # 24 s into the mapping: 15 s of its 30 expected at this pace
        assert log.time_left() == pytest.approx(1.6 * (15.0 + 20.0))
        log(0, None, "adjusting")
    err = capsys.readouterr().err.splitlines()
    assert [STAGE_LINE.match(line) is not None for line in err] == [True, True, True]
    # the mapping ended in 24 s: the two stages done took 40 s for 40 expected
    assert err[0].endswith("; about 80 s left in all") and err[1].endswith("; about 20 s left in all")
    assert "left" not in err[2]  # the last stage: nothing left
