"""The package as a user installs it: an sdist and a wheel built from a clean copy of the checkout, the wheel
built from that sdist, a fresh virtual environment without the training extra, and every command run from
a folder outside the checkout."""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
import tarfile
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "stereogeo_cli"
pytestmark = pytest.mark.slow

# Folders of a checkout that a clean clone has not (used where the checkout is not a git repository)
_NOT_IN_A_CLONE = {".git", "build", "dist", "runs", "data", "data-out", ".venv", "__pycache__"}
_NOT_IN_A_CLONE_SUFFIXES = (".egg-info", "_cache", ".pyc")


def _run(*args, cwd=None, env=None, check=True) -> subprocess.CompletedProcess:
    result = subprocess.run(
        [str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=900
    )
    if check and result.returncode != 0:
        raise AssertionError(f"{args} failed ({result.returncode}):\n{result.stdout}\n{result.stderr}")
    return result


def _checkout_files() -> list[str]:
    """The files of the checkout as a clean clone has them, plus new files not yet committed: what git
    tracks or would track, relative to the repository root."""
    try:
        listed = subprocess.run(
            ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
            cwd=ROOT, capture_output=True, check=True, timeout=60,
        ).stdout  # fmt: skip
        names = [n for n in listed.decode().split("\0") if n]
    except (OSError, subprocess.SubprocessError):
        names = [
            p.relative_to(ROOT).as_posix()
            for p in ROOT.rglob("*")
            if not any(
                part in _NOT_IN_A_CLONE or part.endswith(_NOT_IN_A_CLONE_SUFFIXES)
                for part in p.relative_to(ROOT).parts
            )  # fmt: skip
        ]
    return sorted(n for n in names if (ROOT / n).is_file())


def _package_files() -> list[str]:
    """Every file under stereogeo_cli/ that ships: the modules and any data beside them."""
    return [n for n in _checkout_files() if n.startswith(f"{PACKAGE}/")]


@pytest.fixture(scope="module")
def dists(tmp_path_factory) -> dict[str, Path]:
    """``tree_wheel`` and ``sdist`` built from a clean copy of the checkout; ``wheel`` built from the
    sdist."""
    pytest.importorskip("setuptools")
    work = tmp_path_factory.mktemp("dists")
    tree, dist = work / "tree", work / "dist"
    for name in _checkout_files():
        (tree / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, tree / name)
    for build in (f"build_wheel({str(work / 'tree_dist')!r})", f"build_sdist({str(dist)!r})"):
        _run(sys.executable, "-c", f"from setuptools import build_meta; build_meta.{build}", cwd=tree)
    (tree_wheel,) = (work / "tree_dist").glob("stereogeo-*.whl")
    (sdist,) = dist.glob("stereogeo-*.tar.gz")
    pip_wheel = ("pip", "wheel", "--no-deps", "--no-build-isolation", "-w", dist, sdist)
    _run(sys.executable, "-m", *pip_wheel, cwd=work)
    (wheel,) = dist.glob("stereogeo-*.whl")
    return {"tree_wheel": tree_wheel, "sdist": sdist, "wheel": wheel}


def _wheel_names(path: Path) -> list[str]:
    with zipfile.ZipFile(path) as archive:
        return archive.namelist()


def test_every_file_of_the_package_is_in_the_wheels_and_the_sdist(dists):
    shipped = _package_files()
    assert f"{PACKAGE}/batch/__init__.py" in shipped and f"{PACKAGE}/cli.py" in shipped
    with tarfile.open(dists["sdist"]) as archive:
        in_sdist = {n.split("/", 1)[1] for n in archive.getnames() if "/" in n}
    assert not set(shipped) - in_sdist, "the sdist lacks files of the package"
    for kind in ("tree_wheel", "wheel"):
        names = _wheel_names(dists[kind])
        assert not set(shipped) - set(names), f"the {kind} lacks files of the package"
        assert {f"{PACKAGE}/models/stereogeo.onnx", f"{PACKAGE}/models/MODEL_CARD.md"} <= set(names)
        outside = [n for n in names if not n.startswith((f"{PACKAGE}/", "stereogeo-0.1.0.dist-info/"))]
        assert not outside, f"the {kind} ships files outside the package: {outside}"
        assert not [n for n in names if n.endswith((".pt", ".pyc"))], f"the {kind} ships {names}"
    assert sorted(_wheel_names(dists["tree_wheel"])) == sorted(_wheel_names(dists["wheel"]))


def test_the_sdist_carries_the_model_and_not_the_checkpoint(dists):
    with tarfile.open(dists["sdist"]) as archive:
        names = archive.getnames()
    assert any(n.endswith("models/stereogeo.onnx") for n in names), "the sdist lacks the model"
    assert not any(n.endswith(".pt") for n in names), "the sdist carries the training checkpoint"


@pytest.fixture(scope="module")
def installed(dists, tmp_path_factory) -> Path:
    """The bin/ folder of a fresh virtual environment with the wheel built from the sdist installed."""
    env_dir = tmp_path_factory.mktemp("install") / "venv"
    venv.create(env_dir, with_pip=True)
    bin_dir = env_dir / "bin"
    _run(bin_dir / "python", "-m", "pip", "install", "-q", "--disable-pip-version-check", dists["wheel"])
    return bin_dir


@pytest.fixture(scope="module")
def env(tmp_path_factory) -> dict[str, str]:
    """The user's environment: nothing of this checkout on the path, a cache of the model's own."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["COLUMNS"] = "120"
    env["STEREOGEO_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache"))
    return env


def _stereogeo(installed: Path, *args, cwd: Path, env: dict, code: int = 0) -> subprocess.CompletedProcess:
    """Run the installed command; it must exit with ``code`` and print no traceback."""
    result = _run(installed / "stereogeo", *args, cwd=cwd, env=env, check=False)
    command = " ".join(map(str, args))
    shown = f"stereogeo {command} exited {result.returncode}:\n{result.stdout}\n{result.stderr}"
    assert result.returncode == code, shown
    assert "Traceback" not in result.stdout + result.stderr, shown
    return result


def _example_pair(folder: Path, name: str = "pair") -> tuple[Path, Path]:
    """The bundled example pair copied into ``folder/left/`` and ``folder/right/`` as ``name``.png."""
    copies = []
    for side in ("left", "right"):
        (folder / side).mkdir(parents=True, exist_ok=True)
        copies.append(Path(shutil.copy(ROOT / "examples" / f"{side}.png", folder / side / f"{name}.png")))
    return copies[0], copies[1]


# ------------------------------------------------------------------------------------- the base install
# Each runner runs its command in an empty folder ``work`` as a user would and checks what it wrote.


def _calibrate(run, work: Path) -> None:
    left, right = _example_pair(work)
    report = json.loads(run("calibrate", left, right, "-o", "calibration", "--json").stdout)
    assert report["model"]["file"] == "stereogeo.onnx"
    # the example pair's cameras (examples/ground_truth.json): vFoV 70.6° and 77.0°
    assert abs(report["left"]["vfov_deg"] - 70.6) < 10 and abs(report["right"]["vfov_deg"] - 77.0) < 10
    written = sorted(p.name for p in (work / "calibration").iterdir())
    assert written == [
        "camchain.yaml", "cameras.txt", "extrinsics.yml", "intrinsics.yml", "left.yaml", "report.html",
        "report.json", "right.yaml",
    ]  # fmt: skip


def _batch_calibrate(run, work: Path) -> None:
    for name in ("a", "b"):
        _example_pair(work / "pairs", name)
    result = run("batch-calibrate", "pairs", "-o", "out", "--workers", "2", "--format", "opencv,json")
    assert "2 pairs: 2 ok, 0 failed" in result.stdout
    with open(work / "out" / "summary.csv", newline="") as file:
        rows = list(csv.DictReader(file))
    assert [(r["name"], r["status"]) for r in rows] == [("a", "ok"), ("b", "ok")]
    assert (work / "out" / "summary.json").is_file() and (work / "out" / "b" / "report.json").is_file()


def _evaluate(run, work: Path) -> None:
    truth = json.loads((ROOT / "examples" / "ground_truth.json").read_text())
    _example_pair(work / "set", truth["id"])
    (work / "set" / "calib.jsonl").write_text(json.dumps(truth) + "\n")
    results = json.loads(run("evaluate", "set", "--json", "--baselines", "--plot", "cdf.png").stdout)
    assert results["metrics"]["pairs"] == {"evaluated": 1, "total": 1}
    assert results["metrics"]["vfov_deg"]["median"] < 10
    assert (work / "cdf.png").stat().st_size > 0


def _calibrate_sequence(run, work: Path) -> None:
    for name in (
        "f1",
        "f2",
        "f3",
    ):  # a rig that stands still: COLMAP has nothing to map, the pairs calibrate it
        _example_pair(work / "seq", name)
    report = json.loads(run("calibrate-sequence", "seq", "-o", "out", "--json").stdout)
    assert report["sequence"]["frames_read"] == 3 and report["sequence"]["focal_observable"] is False
    assert abs(report["left"]["vfov_deg"] - 70.6) < 10
    assert (work / "out" / "report.json").is_file() and (work / "out" / "intrinsics.yml").is_file()


# Every command of the base install (no training extra) and its runner above: a new command gets a line.
BASE_COMMANDS = {
    "calibrate": _calibrate,
    "batch-calibrate": _batch_calibrate,
    "calibrate-sequence": _calibrate_sequence,
    "evaluate": _evaluate,
}
# The commands of the training extra and arguments they take: without it, one line naming the extra.
TRAINING_COMMANDS = {
    "make-data": ["out"],
    "train": [],
    "export-onnx": ["x.pt"],
    "average-checkpoints": ["a.pt", "b.pt", "-o", "c.pt"],
}


def test_the_lists_name_every_command(installed, env, tmp_path):
    code = "import typer.main, stereogeo_cli.cli as cli; print(*typer.main.get_command(cli.app).commands)"
    commands = _run(installed / "python", "-c", code, cwd=tmp_path, env=env).stdout.split()
    assert sorted(commands) == sorted([*BASE_COMMANDS, *TRAINING_COMMANDS])


@pytest.mark.parametrize("command", sorted(BASE_COMMANDS))
def test_installed_command_runs_without_torch(installed, env, tmp_path, command):
    assert _run(installed / "python", "-c", "import torch", check=False, env=env).returncode != 0
    BASE_COMMANDS[command](lambda *args: _stereogeo(installed, *args, cwd=tmp_path, env=env), tmp_path)


@pytest.mark.parametrize(
    "command",
    [[], *([c] for c in sorted([*BASE_COMMANDS, *TRAINING_COMMANDS]))],
    ids=lambda command: " ".join(["stereogeo", *command]),
)
def test_installed_help(installed, env, tmp_path, command):
    result = _stereogeo(installed, *command, "--help", cwd=tmp_path, env=env)
    assert "Usage: stereogeo" in result.stdout


def test_installed_version_names_the_model(installed, env, tmp_path):
    result = _stereogeo(installed, "--version", cwd=tmp_path, env=env)
    assert result.stdout.startswith("stereogeo ") and "model stereogeo-" in result.stdout


@pytest.mark.parametrize("command", sorted(TRAINING_COMMANDS))
def test_training_commands_without_the_extra_say_what_to_install(installed, env, tmp_path, command):
    result = _stereogeo(installed, command, *TRAINING_COMMANDS[command], cwd=tmp_path, env=env, code=2)
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and 'pip install "stereogeo[train]"' in lines[0]


def test_training_help_says_what_to_install(installed, env, tmp_path):
    result = _stereogeo(installed, "train", "--help", cwd=tmp_path, env=env)
    assert 'pip install "stereogeo[train]"' in result.stdout
    result = _stereogeo(installed, "make-data", "--help", cwd=tmp_path, env=env)
    assert "--count" in result.stdout
