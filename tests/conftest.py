import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"
sys.path.insert(0, str(Path(__file__).parent))  # test helpers such as synthetic_fields


# CI (.ci/run) sets this: there the data pack is always beside the clone, and a test that needs it must run,
# not skip without a word (the only independent check of the field formulas, test_golden_fields, is one)
REQUIRE_SHARED_DATA = "STEREOGEO_REQUIRE_SHARED_DATA"


@pytest.fixture
def shared_data() -> Path:
    """The developer data pack beside the repo (every test that reads it takes this fixture): absent, the
    test skips, or fails where ``STEREOGEO_REQUIRE_SHARED_DATA=1`` (CI)."""
    if not SHARED_DATA.is_dir():
        message = f"../shared/data is not present ({SHARED_DATA})"
        if os.environ.get(REQUIRE_SHARED_DATA, "") not in ("", "0"):
            pytest.fail(f"{message}, and {REQUIRE_SHARED_DATA} is set: the data pack is required here")
        pytest.skip(message)
    return SHARED_DATA


@pytest.fixture(scope="session")
def onnx_model(tmp_path_factory) -> Path:
    """The shipped model if it is there, else an untrained network exported for the test session.

    Tests of the product's plumbing (files, errors, formats) use it; tests of accuracy need the shipped
    model and skip without it.
    """
    shipped = ROOT / "models" / "stereogeo.onnx"
    if shipped.is_file():
        return shipped
    torch = pytest.importorskip("torch")
    from stereogeo_cli.network.export import export_onnx
    from stereogeo_cli.network.model import StereoGeoNet

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("model") / "stereogeo.onnx"
    export_onnx(StereoGeoNet({"pretrained": False}).eval(), path, model_version="untrained-test",
                training_data="none", parity_sizes=((64, 96),))  # fmt: skip
    return path


@pytest.fixture(scope="session")
def example_pair(tmp_path_factory) -> tuple[Path, Path]:
    """A rendered stereo pair (PNG files) with enough texture to match features."""
    shipped = ROOT / "examples"
    if (shipped / "left.png").is_file() and (shipped / "right.png").is_file():
        return shipped / "left.png", shipped / "right.png"
    from stereogeo_cli.synth.config import SynthConfig
    from stereogeo_cli.synth.dataset import make_dataset

    folder = tmp_path_factory.mktemp("pair")
    make_dataset(folder, 1, 3, SynthConfig(short_side=240, panorama_share=0.0), workers=1, progress=False)
    return folder / "left" / "000000.png", folder / "right" / "000000.png"


# Rendered pairs with exact ground truth (make-data's renderer at its default 240 px, no panoramas), pair 0 of
# each seed: seeds after the held-out ones the README lists, never used in training. Four sizes and scenes
# (tests/test_accuracy.py says which are held to accuracy and why those).
RENDERED_SEEDS = {
    "street-wide": 960011,  # 240 x 240, vFoV 90°, pitched 36° up
    "street-long": 960041,  # 360 x 240, vFoV 37°
    "open-portrait": 960047,  # 240 x 360, vFoV 25°, level
    "street-square": 960059,  # 240 x 240, vFoV 82°
}


@dataclass(frozen=True)
class RenderedPair:
    left: Path
    right: Path
    truth: dict  # the pair's calib.jsonl record: K, gravity_up per camera, R, T


@pytest.fixture(scope="session")
def rendered_pairs(tmp_path_factory) -> dict[str, RenderedPair]:
    """The pairs of ``RENDERED_SEEDS``, rendered once per session (a few seconds each)."""
    from stereogeo_cli.synth.config import SynthConfig
    from stereogeo_cli.synth.dataset import make_dataset

    root = tmp_path_factory.mktemp("renders")
    pairs = {}
    for name, seed in RENDERED_SEEDS.items():
        folder = root / name
        make_dataset(folder, 1, seed, SynthConfig(panorama_share=0.0), workers=1, progress=False)
        truth = json.loads((folder / "calib.jsonl").read_text().splitlines()[0])
        left, right = (folder / side / f"{truth['id']}.png" for side in ("left", "right"))
        pairs[name] = RenderedPair(left, right, truth)
    return pairs


@pytest.fixture(scope="session")
def calibrate_cli(tmp_path_factory):
    """``stereogeo calibrate LEFT RIGHT --json -o DIR`` with the shipped model, as a user runs it, once per
    pair in a session: returns (the JSON report on stdout, DIR with every format)."""
    from typer.testing import CliRunner

    from stereogeo_cli.cli import app

    done: dict[tuple[str, str], tuple[dict, Path]] = {}

    def run(left: Path, right: Path) -> tuple[dict, Path]:
        key = (str(left), str(right))
        if key not in done:
            out = tmp_path_factory.mktemp("calibrate-o")
            result = CliRunner().invoke(app, ["calibrate", str(left), str(right), "--json", "-o", str(out)])
            assert result.exit_code == 0, result.output
            done[key] = json.loads(result.stdout), out
        return done[key]

    return run


@pytest.fixture(scope="session")
def calibrate_api():
    """``stereogeo_cli.calibrate(left, right, calibrator=...)`` with the shipped model and one Calibrator for
    the session (as the README says to for many pairs), once per pair: returns ``result.report()``."""
    import stereogeo_cli

    done: dict[tuple[str, str], dict] = {}
    calibrator = []

    def run(left: Path, right: Path) -> dict:
        key = (str(left), str(right))
        if key not in done:
            if not calibrator:
                calibrator.append(stereogeo_cli.Calibrator(threads=1))
            done[key] = stereogeo_cli.calibrate(left, right, calibrator=calibrator[0]).report()
        return done[key]

    return run
