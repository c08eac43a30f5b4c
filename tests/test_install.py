"""The package as a user installs it: an sdist, the wheel built from it, a fresh virtual environment without
the training extra, and the CLI run from a folder outside the checkout."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tarfile
import venv
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
pytestmark = pytest.mark.slow


def _run(*args, cwd=None, env=None, check=True) -> subprocess.CompletedProcess:
    result = subprocess.run(
        [str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=900
    )
    if check and result.returncode != 0:
        raise AssertionError(f"{args} failed ({result.returncode}):\n{result.stdout}\n{result.stderr}")
    return result


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The bin/ folder of a fresh virtual environment with the wheel (built from the sdist) installed."""
    pytest.importorskip("setuptools")
    work = tmp_path_factory.mktemp("install")
    dist = work / "dist"
    code = f"from setuptools import build_meta; build_meta.build_sdist({str(dist)!r})"
    _run(sys.executable, "-c", code, cwd=ROOT)
    (sdist,) = dist.glob("stereogeo-*.tar.gz")
    with tarfile.open(sdist) as archive:
        names = archive.getnames()
    assert any(n.endswith("models/stereogeo.onnx") for n in names), "the sdist lacks the model"
    assert not any(n.endswith(".pt") for n in names), "the sdist carries the training checkpoint"
    _run(sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", dist, sdist)
    (wheel,) = dist.glob("stereogeo-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        assert "stereogeo_cli/models/stereogeo.onnx" in archive.namelist()
    env_dir = work / "venv"
    venv.create(env_dir, with_pip=True)
    bin_dir = env_dir / "bin"
    _run(bin_dir / "python", "-m", "pip", "install", "-q", wheel)
    return bin_dir


def _env() -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["COLUMNS"] = "120"
    return env


def test_installed_wheel_calibrates_the_example_pair_without_torch(installed, tmp_path):
    assert _run(installed / "python", "-c", "import torch", check=False, env=_env()).returncode != 0
    out = tmp_path / "calibration"
    result = _run(
        installed / "stereogeo", "calibrate", ROOT / "examples/left.png", ROOT / "examples/right.png",
        "-o", out, "--json", cwd=tmp_path, env=_env(),
    )  # fmt: skip
    report = json.loads(result.stdout)
    assert report["model"]["file"] == "stereogeo.onnx"
    # the example pair's cameras (examples/ground_truth.json): vFoV 70.6° and 77.0°
    assert abs(report["left"]["vfov_deg"] - 70.6) < 10 and abs(report["right"]["vfov_deg"] - 77.0) < 10
    written = sorted(p.name for p in out.iterdir())
    assert written == [
        "camchain.yaml", "cameras.txt", "extrinsics.yml", "intrinsics.yml", "left.yaml", "report.json",
        "right.yaml",
    ]  # fmt: skip


def test_installed_version_names_the_model(installed, tmp_path):
    result = _run(installed / "stereogeo", "--version", cwd=tmp_path, env=_env())
    assert result.stdout.startswith("stereogeo ") and "model stereogeo-" in result.stdout


@pytest.mark.parametrize("command", [["train"], ["make-data", "out"], ["export-onnx", "x.pt"]])
def test_training_commands_without_the_extra_say_what_to_install(installed, tmp_path, command):
    result = _run(installed / "stereogeo", *command, cwd=tmp_path, env=_env(), check=False)
    assert result.returncode == 2
    assert result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and 'pip install "stereogeo[train]"' in lines[0]
    assert "Traceback" not in result.stderr


def test_training_help_works_without_the_extra(installed, tmp_path):
    result = _run(installed / "stereogeo", "train", "--help", cwd=tmp_path, env=_env())
    assert 'pip install "stereogeo[train]"' in result.stdout
    result = _run(installed / "stereogeo", "make-data", "--help", cwd=tmp_path, env=_env())
    assert "--count" in result.stdout
