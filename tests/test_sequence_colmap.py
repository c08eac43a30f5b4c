"""The bridge to COLMAP (``stereogeo_cli.sequence.colmap``) on its own: where COLMAP's log goes, and an
adjustment whose solver found no usable solution."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("pycolmap")

ROOT = Path(__file__).resolve().parents[1]
GLOG_LINE = re.compile(r"^[IWEF]\d{8} \d\d:\d\d:\d\d\.\d+ ", re.MULTILINE)  # "I20250101 12:00:00.123 …"

# COLMAP's mapping of an empty database, in and out of logging_into: an INFO, a WARNING and an ERROR line
SCRIPT = textwrap.dedent(
    """
    import sys
    from pathlib import Path

    from stereogeo_cli.sequence import colmap

    workspace = Path(sys.argv[1])
    pycolmap = colmap._pycolmap()
    flags = {name: getattr(pycolmap.logging, name) for name in colmap._GLOG_FLAGS}
    with pycolmap.Database.open(workspace / "database.db"):
        pass

    def mapping():
        return pycolmap.incremental_mapping(workspace / "database.db", workspace, workspace / "mapping")

    mapping()  # outside: its lines go nowhere
    with colmap.logging_into(workspace) as log:
        mapping()
        with colmap.logging_into(workspace / "elsewhere") as inner:  # inside one: the outer log
            pycolmap.logging.info("the inner block's line")
    mapping()
    assert inner == log == workspace / "colmap.log", (inner, log)
    assert {name: getattr(pycolmap.logging, name) for name in colmap._GLOG_FLAGS} == flags
    """
)


def _python(script: str, *args, tmp: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "TMPDIR": str(tmp), "TMP": str(tmp)}
    return subprocess.run(
        [sys.executable, "-c", script, *map(str, args)], capture_output=True, text=True, timeout=300, env=env
    )


def test_colmaps_log_goes_to_the_workspace_and_none_of_it_to_stderr(tmp_path):
    workspace, tmp = tmp_path / "workspace", tmp_path / "tmp"
    workspace.mkdir()
    tmp.mkdir()
    done = _python(SCRIPT, workspace, tmp=tmp)
    assert done.returncode == 0, done.stderr
    assert done.stderr == "" and done.stdout == ""
    log = (workspace / "colmap.log").read_text()
    for line in ("Loading database", "No images with matches", "Failed to create any sparse model"):
        assert log.count(line) == 1, (line, log)  # the mapping inside the block, once: not those outside
    assert re.search(r"^I.*incremental_pipeline\.cc:\d+\] Loading database$", log, re.MULTILINE)
    assert re.search(r"^W.* No images with matches$", log, re.MULTILINE)
    assert re.search(r"^E.* Failed to create any sparse model$", log, re.MULTILINE)
    assert "the inner block's line" in log
    # glog's own file in the workspace was folded into the log; it made no file elsewhere (its /tmp)
    assert sorted(p.name for p in workspace.iterdir()) == ["colmap.log", "database.db", "mapping"]
    assert list(tmp.iterdir()) == []


def test_a_second_block_appends_to_the_log(tmp_path):
    workspace = tmp_path / "workspace"
    workspace.mkdir()
    script = textwrap.dedent(
        """
        import sys
        from stereogeo_cli.sequence import colmap

        pycolmap = colmap._pycolmap()
        for n in range(3):  # the same second, the same process: glog's file name would be the same
            with colmap.logging_into(sys.argv[1]):
                pycolmap.logging.warning(f"block {n}")
        """
    )
    done = _python(script, workspace, tmp=tmp_path)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    log = (workspace / "colmap.log").read_text()
    assert re.findall(r"block \d", log) == ["block 0", "block 1", "block 2"]
    assert [p.name for p in workspace.iterdir()] == ["colmap.log"]


class _Unusable:
    """A solver summary as pycolmap returns it where Ceres ran and failed."""

    class termination_type:  # noqa: N801 - pycolmap's enum value
        name = "FAILURE"

    class ceres_summary:  # noqa: N801
        message = "Residual and Jacobian evaluation\nfailed."
        final_cost = 1.0
        num_residuals_reduced = 10
        num_effective_parameters_reduced = 2

    def is_solution_usable(self) -> bool:
        return False


def test_an_unusable_adjustment_is_calibration_failed(monkeypatch):
    from stereogeo_cli.errors import CalibrationFailed
    from stereogeo_cli.sequence import colmap

    pycolmap = colmap._pycolmap()
    # a real one: nothing to adjust, no residual (COLMAP's FAILURE, Ceres never runs)
    with pytest.raises(CalibrationFailed, match=r"^COLMAP's bundle adjustment found no usable solution"):
        colmap._bundle_adjust(pycolmap.Reconstruction(), radial=False, refine_focal=True)

    class Adjuster:
        def solve(self):
            return _Unusable()

    monkeypatch.setattr(pycolmap, "create_default_ceres_bundle_adjuster", lambda *args: Adjuster())
    with pytest.raises(CalibrationFailed) as failed:
        colmap._bundle_adjust(pycolmap.Reconstruction(), radial=False, refine_focal=False)
    assert str(failed.value) == (
        "COLMAP's bundle adjustment found no usable solution "
        "(FAILURE: Residual and Jacobian evaluation failed.)"
    )
    assert "\n" not in str(failed.value)


@pytest.mark.slow
def test_a_sequence_keeps_colmaps_log_in_its_workspace_and_its_stderr_clean(tmp_path):
    pytest.importorskip("moderngl")
    from stereogeo_cli.synth.sequence import make_sequence, sequence_config

    folder, workspace = tmp_path / "seq", tmp_path / "workspace"
    make_sequence(
        folder, "turning", 16, 7, sequence_config(short_side=240, outdoor_share=0.0), progress=False
    )
    done = subprocess.run(
        [sys.executable, "-m", "stereogeo_cli", "calibrate-sequence", str(folder), "--json", "--no-progress",
         "--workspace", str(workspace)],
        capture_output=True, text=True, timeout=900, env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["sequence"]["frames_registered"] == 16
    assert not GLOG_LINE.search(done.stderr), done.stderr
    log = (workspace / "colmap.log").read_text()
    # the mapping's lines among many of COLMAP's
    assert re.search(r"^I.*incremental_pipeline\.cc:\d+\] Loading database$", log, re.MULTILINE)
    assert len(GLOG_LINE.findall(log)) > 50
    assert not [p.name for p in workspace.iterdir() if p.name.startswith(".colmap.log")]


def _returning_frames(images: Path, first: int = 11) -> None:
    """A rig panning along a textured wall and back to where it started: frames 0..first-1, then the same
    views again (frame first + k shows what frame k showed), the right camera 12 px to the side."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(3)
    wall = cv2.GaussianBlur(rng.integers(0, 256, (300, 1400, 3), dtype=np.uint8), (0, 0), 1.5)
    spots = rng.integers(0, 1400, 400), rng.integers(0, 300, 400), rng.integers(4, 25, 400)
    for x, y, r in zip(*spots, strict=True):
        cv2.circle(wall, (int(x), int(y)), int(r), tuple(int(c) for c in rng.integers(0, 256, 3)), -1)
    for side, shift in (("left", 0), ("right", 12)):
        (images / side).mkdir(parents=True)
        for k in range(2 * first):
            x0 = 40 * (k % first) + shift
            cv2.imwrite(str(images / side / f"{k:06d}.png"), wall[20:260, x0 : x0 + 320])


@pytest.mark.parametrize("loops", [False, True])
def test_loop_detection_matches_the_frames_where_the_rig_came_back(tmp_path, loops, capfd):
    """Frames 11 apart show the same view, farther than the sequential matching reaches (1-3, 4, 8 frames
    on): only loop detection, with a vocabulary built from the frames' own features, matches them."""
    import numpy as np

    from stereogeo_cli.sequence import colmap

    _returning_frames(tmp_path / "images")
    starts = tuple(colmap.CameraStart(300.0, 320, 240, False) for _ in range(2))
    conf = {"loop_detection": {"enabled": loops, "period": 1, "min_frames": 2}, "threads": 2}
    with colmap.logging_into(tmp_path):
        database = colmap.match_frames(tmp_path, starts, np.eye(3), np.array([-0.1, 0.0, 0.0]), conf)
    pycolmap = colmap._pycolmap()
    with pycolmap.Database.open(database) as db:
        names = {image.image_id: image.name for image in db.read_all_images()}
        pair_ids = db.read_two_view_geometries()[0]
    frames = [sorted(int(names[i][-10:-4]) for i in pycolmap.pair_id_to_image_pair(p)) for p in pair_ids]
    came_back = [(a, b) for a, b in frames if b - a == 11]
    assert bool(came_back) == loops, frames
    assert (tmp_path / "vocabulary.bin").exists() == loops
    # the vocabulary's clustering warns of too few points per word: into COLMAP's log, not onto stderr
    assert "clustering" in (tmp_path / "colmap.log").read_text() or not loops
    assert "clustering" not in capfd.readouterr().err
