import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"
sys.path.insert(0, str(Path(__file__).parent))  # test helpers such as synthetic_fields


@pytest.fixture
def shared_data() -> Path:
    """The developer data pack beside the repo; tests that need it skip when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present")
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
