"""Weight averages of checkpoints (stereogeo average-checkpoints): the arithmetic, the provenance, the
refusals, and that the result exports and runs like any checkpoint."""

import pytest
import torch
from typer.testing import CliRunner

from stereogeo_cli.cli import app
from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.network.checkpoint import average_checkpoints, load_checkpoint, save_checkpoint
from stereogeo_cli.network.model import StereoGeoNet
from stereogeo_cli.network.runtime import file_sha256

SMALL = {"pretrained": False, "decoder_dim": 16, "head_dim": 8, "pose_reduce_dim": 16, "pose_hidden_dim": 32}


def _checkpoint(path, seed, conf=SMALL, **extra):
    torch.manual_seed(seed)
    model = StereoGeoNet(conf)
    with torch.no_grad():  # batch-norm statistics differ too, as after training
        for buffer in model.buffers():
            if buffer.is_floating_point():
                buffer.add_(torch.rand_like(buffer))
    return save_checkpoint(path, model, step=100 * seed, **extra), model


def test_the_average_is_the_weighted_mean_of_every_float_tensor(tmp_path):
    a_path, a = _checkpoint(tmp_path / "a.pt", 1, model_version="m-a", lineage="m1 -> m2", optimizer={"x": 1})
    b_path, b = _checkpoint(tmp_path / "b.pt", 2, model_version="m-b")
    average = average_checkpoints([a_path, b_path], [3.0, 1.0])  # scaled to 0.75 / 0.25
    sa, sb = a.state_dict(), b.state_dict()
    floats = [k for k, v in sa.items() if v.is_floating_point()]
    assert any("running_var" in k for k in floats)
    for name in floats:
        expected = 0.75 * sa[name].double() + 0.25 * sb[name].double()
        torch.testing.assert_close(average["model"][name], expected.float(), rtol=0, atol=1e-6)
        assert average["model"][name].dtype == sa[name].dtype
    for name, tensor in sa.items():
        if not tensor.is_floating_point():
            assert torch.equal(average["model"][name], tensor)
    # provenance: each input named and hashed with its share; the run state of the first is not carried
    sources = average["averaged_from"]
    assert [s["model_version"] for s in sources] == ["m-a", "m-b"]
    assert [s["weight"] for s in sources] == [0.75, 0.25]
    assert sources[0]["sha256"] == file_sha256(a_path)
    assert average["lineage"].startswith("m1 -> m2 -> weight average 0.75 × m-a + 0.25 × m-b")
    assert "optimizer" not in average and average["model_version"] == "m-a"


def test_equal_checkpoints_average_to_themselves_and_the_cli_writes_a_loadable_file(tmp_path):
    a_path, a = _checkpoint(tmp_path / "a.pt", 1, model_version="m-a")
    b_path, b = _checkpoint(tmp_path / "b.pt", 2, model_version="m-b")
    out = tmp_path / "soup" / "avg.pt"
    result = CliRunner().invoke(
        app,
        [
            "average-checkpoints",
            str(a_path),
            str(b_path),
            "-o",
            str(out),
            "--model-version",
            "soup-1",
            "--lineage",
            "b: a fine-tune",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "0.5 × m-a, 0.5 × m-b" in result.output
    loaded, checkpoint = load_checkpoint(out)
    assert checkpoint["model_version"] == "soup-1"
    assert checkpoint["lineage"] == "0.5 × m-a + 0.5 × m-b (b: a fine-tune)"
    x = torch.rand(1, 3, 64, 96)
    with torch.no_grad():
        mean = {
            k: 0.5 * (v + b.state_dict()[k]) if v.is_floating_point() else v
            for k, v in a.state_dict().items()
        }
        reference = StereoGeoNet(SMALL)
        reference.load_state_dict(mean)
        reference.eval()
        torch.testing.assert_close(
            loaded(x, x)["left_latitude"], reference(x, x)["left_latitude"], atol=1e-5, rtol=0
        )
    same = average_checkpoints([a_path, a_path], [1.0, 2.0])
    for name, tensor in a.state_dict().items():
        torch.testing.assert_close(same["model"][name], tensor, atol=1e-6, rtol=0)


def test_checkpoints_of_different_models_or_bad_weights_are_refused(tmp_path):
    a_path, _ = _checkpoint(tmp_path / "a.pt", 1)
    other_path, _ = _checkpoint(tmp_path / "other.pt", 2, conf={**SMALL, "head_dim": 16})
    with pytest.raises(StereoGeoError, match="different model"):
        average_checkpoints([a_path, other_path], [1.0, 1.0])
    with pytest.raises(StereoGeoError, match="at least two"):
        average_checkpoints([a_path], [1.0])
    with pytest.raises(StereoGeoError, match="positive"):
        average_checkpoints([a_path, a_path], [1.0, 0.0])
    with pytest.raises(StereoGeoError, match="2 weights"):
        average_checkpoints([a_path, a_path], [1.0])
    runner = CliRunner()
    out = tmp_path / "avg.pt"
    out.write_bytes(b"keep me")
    for args in (
        [str(a_path), str(other_path)],
        [str(a_path), str(a_path), "--weights", "1,x"],
        [str(a_path), str(tmp_path / "missing.pt")],
    ):
        result = runner.invoke(app, ["average-checkpoints", *args, "-o", str(out)])
        assert result.exit_code != 0 and "Traceback" not in result.output
        assert len(result.output.strip().splitlines()) == 1, result.output
        assert out.read_bytes() == b"keep me"  # nothing already there is lost
    folder = runner.invoke(app, ["average-checkpoints", str(a_path), str(a_path), "-o", str(tmp_path)])
    assert folder.exit_code != 0 and "is a folder" in folder.output


def test_a_fine_tune_averages_with_the_checkpoint_it_started_from(tmp_path):
    """A fine-tune's conf spells out defaults its start left implicit and has ``pretrained`` off: the same
    model, and the average is taken."""
    start, _ = _checkpoint(tmp_path / "start.pt", 1)
    tuned, _ = _checkpoint(tmp_path / "tuned.pt", 2, conf={**SMALL, "input_blur_px": 0.0, "pretrained": True})
    average_checkpoints([start, tuned], [1.0, 1.0])
    blurred, _ = _checkpoint(tmp_path / "blurred.pt", 3, conf={**SMALL, "input_blur_px": 1.5})
    with pytest.raises(StereoGeoError, match="different model"):
        average_checkpoints([start, blurred], [1.0, 1.0])
