"""ONNX export of StereoGeoNet (parity, metadata, dynamic sizes) and the torch-free runtime."""

import os
import subprocess
import sys

import numpy as np
import onnx
import pytest
import torch

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.network.checkpoint import save_checkpoint
from stereogeo_cli.network.export import export_onnx
from stereogeo_cli.network.model import OUTPUT_NAMES, StereoGeoNet
from stereogeo_cli.network.runtime import FieldNetwork, cell_pixel_coordinates

torch.set_num_threads(2)

PARITY_SIZES = ((256, 256), (192, 320))  # (height, width): square and non-square


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return StereoGeoNet().eval()


@pytest.fixture(scope="module")
def exported(model, tmp_path_factory):
    path = tmp_path_factory.mktemp("onnx") / "stereogeo.onnx"
    report = export_onnx(model, path, model_version="test-1", training_data="none", parity_sizes=PARITY_SIZES)
    return path, report


def test_export_parity_with_torch(exported):
    path, report = exported
    assert path.is_file() and report["path"] == path
    assert set(report["max_abs_error"]) == set(OUTPUT_NAMES)
    assert max(report["max_abs_error"].values()) <= 1e-4
    assert not list(path.parent.glob(".*.tmp"))
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # a new file's mode, not mkstemp's 0600


def test_exported_graph_has_dynamic_inputs_and_metadata(exported):
    path, _ = exported
    proto = onnx.load(str(path))
    assert proto.opset_import[0].version >= 17
    assert not any(t.data_location == onnx.TensorProto.EXTERNAL for t in proto.graph.initializer)
    shapes = {
        i.name: [d.dim_param or d.dim_value for d in i.type.tensor_type.shape.dim] for i in proto.graph.input
    }
    assert shapes == {
        "left": ["batch", 3, "left_height", "left_width"],
        "right": ["batch", 3, "right_height", "right_width"],
    }
    assert [o.name for o in proto.graph.output] == list(OUTPUT_NAMES)
    meta = {p.key: p.value for p in proto.metadata_props}
    keys = (
        "input_size_rule",
        "normalization",
        "stereogeo_version",
        "output_stride",
        "training_data",
        "model_version",
        "input_short_side",
        "input_multiple",
        "field_coordinates",
        "pose_convention",
    )
    for key in keys:
        assert meta[key], key
    assert meta["model_version"] == "test-1" and meta["output_stride"] == "4"


def test_runtime_matches_torch_on_real_preprocessing(model, exported):
    path, _ = exported
    network = FieldNetwork(path, threads=2)
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)  # 4:3 → 320 x 426 → crop 320 x 416
    right = rng.integers(0, 256, (400, 300, 3), dtype=np.uint8)  # portrait, a different size
    out = network.predict(left, right)

    assert out.left.image_size == (416, 320) and out.right.image_size == (320, 416)
    assert out.left.up.shape == (80, 104, 2) and out.left.latitude.shape == (80, 104)
    assert out.right.up.shape == (104, 80, 2) and out.right.up_confidence.shape == (104, 80)
    np.testing.assert_allclose(np.linalg.norm(out.left.up, axis=-1), 1.0, atol=1e-5)
    x, y = out.left.pixel_xy
    assert x.shape == (80, 104) and x[0, 0] == 1.5 and x[0, 1] == 5.5 and y[1, 0] == 5.5
    np.testing.assert_array_equal(out.right.pixel_xy[0], cell_pixel_coordinates(104, 80, 4)[0])
    assert out.left.resize_crop.focal_to_input(320.0) == pytest.approx(240.0)
    assert np.linalg.norm(out.quaternion) == pytest.approx(1.0) and out.quaternion[0] >= 0
    np.testing.assert_allclose(out.rotation @ out.rotation.T, np.eye(3), atol=1e-6)

    tensors = [torch.from_numpy(network.prepare(image)[0]) for image in (left, right)]
    with torch.no_grad():
        expected = model(*tensors)
    np.testing.assert_allclose(out.left.up, expected["left_up"][0].permute(1, 2, 0).numpy(), atol=1e-4)
    np.testing.assert_allclose(out.right.latitude, expected["right_latitude"][0].numpy(), atol=1e-4)
    np.testing.assert_allclose(out.translation, expected["translation"][0].numpy(), atol=1e-4)
    assert len(network.model_sha256) == 64


def test_export_from_checkpoint_file(tmp_path):
    model = StereoGeoNet(
        {"pretrained": False, "decoder_dim": 32, "head_dim": 16, "pose_reduce_dim": 32, "pose_hidden_dim": 64}
    )
    ckpt = save_checkpoint(tmp_path / "small.pt", model, step=123, training_data="unit-test renders")
    report = export_onnx(ckpt, tmp_path / "small.onnx", parity_sizes=((64, 64), (64, 128)))
    assert report["metadata"]["training_step"] == "123"
    assert report["metadata"]["training_data"] == "unit-test renders"
    assert FieldNetwork(tmp_path / "small.onnx").metadata["model_version"] == "untrained"


def test_a_depth_head_is_exported_after_the_other_outputs_and_read_by_the_runtime(tmp_path):
    torch.manual_seed(1)
    small = {
        "pretrained": False,
        "decoder_dim": 32,
        "head_dim": 16,
        "pose_reduce_dim": 32,
        "pose_hidden_dim": 64,
    }
    model = StereoGeoNet({**small, "depth_head": True, "depth_dim": 16}).eval()
    report = export_onnx(model, tmp_path / "depth.onnx", parity_sizes=((64, 96), (96, 64)))
    names = list(OUTPUT_NAMES) + [f"{v}_{k}" for v in ("left", "right") for k in ("depth", "depth_spread")]
    assert [o.name for o in onnx.load(tmp_path / "depth.onnx").graph.output] == names
    assert set(report["max_abs_error"]) == set(names) and max(report["max_abs_error"].values()) < 1e-4
    network = FieldNetwork(tmp_path / "depth.onnx", threads=1)
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    out = network.predict(image, image[:, ::-1].copy())
    for view in (out.left, out.right):
        width, height = view.image_size
        assert view.depth.shape == view.depth_spread.shape == (height // 8, width // 8)
    with torch.no_grad():
        expected = model(*(torch.from_numpy(network.prepare(im)[0]) for im in (image, image[:, ::-1].copy())))
    np.testing.assert_allclose(out.left.depth, expected["left_depth"][0].numpy(), atol=1e-4)
    # a model without one leaves them out
    plain = FieldNetwork(_small_export(tmp_path), threads=1).predict(image, image)
    assert plain.left.depth is None and plain.right.depth_spread is None


def _small_export(tmp_path):
    model = StereoGeoNet(
        {"pretrained": False, "decoder_dim": 16, "head_dim": 8, "pose_reduce_dim": 16, "pose_hidden_dim": 32}
    )
    export_onnx(model, tmp_path / "plain.onnx", parity_sizes=((64, 64),))
    return tmp_path / "plain.onnx"


def test_failed_parity_check_writes_no_file(tmp_path):
    model = StereoGeoNet(
        {"pretrained": False, "decoder_dim": 16, "head_dim": 8, "pose_reduce_dim": 16, "pose_hidden_dim": 32}
    )
    with pytest.raises(StereoGeoError, match="parity") as info:
        export_onnx(model, tmp_path / "m.onnx", parity_sizes=((64, 64), (64, 96)), atol=0.0)
    assert info.value.exit_code == 1
    assert list(tmp_path.iterdir()) == []


def test_runtime_does_not_import_torch():
    code = (
        "import sys, stereogeo_cli.network.runtime, stereogeo_cli.network; "
        "assert 'torch' not in sys.modules, 'torch imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize(
    "content, message",
    [(None, "not found"), (b"", "not a valid ONNX"), (b"this is not a model", "not a valid ONNX")],
)
def test_bad_model_files_raise_stereogeo_error(tmp_path, content, message):
    path = tmp_path / "model.onnx"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(StereoGeoError, match=message) as info:
        FieldNetwork(path)
    assert info.value.exit_code == 2
    assert "\n" not in str(info.value)


def test_truncated_and_foreign_models_raise_stereogeo_error(tmp_path, exported):
    path, _ = exported
    with pytest.raises(StereoGeoError, match="not a file"):
        FieldNetwork(tmp_path)
    truncated = tmp_path / "truncated.onnx"
    truncated.write_bytes(path.read_bytes()[:200_000])
    with pytest.raises(StereoGeoError, match="not a valid ONNX"):
        FieldNetwork(truncated)
    # A valid ONNX model that is not ours.
    x = onnx.helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [1])
    y = onnx.helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [1])
    graph = onnx.helper.make_graph([onnx.helper.make_node("Identity", ["x"], ["y"])], "g", [x], [y])
    foreign = tmp_path / "foreign.onnx"
    onnx.save(onnx.helper.make_model(graph, opset_imports=[onnx.helper.make_opsetid("", 18)]), str(foreign))
    with pytest.raises(StereoGeoError, match="not a stereogeo network"):
        FieldNetwork(foreign)


def test_export_cli_records_the_pose_heads_sigmas_and_calibrate_leans_on_them(tmp_path):
    from typer.testing import CliRunner

    from stereogeo_cli.cli import app
    from stereogeo_cli.pipeline import Calibrator

    model = StereoGeoNet(
        {"pretrained": False, "decoder_dim": 16, "head_dim": 8, "pose_reduce_dim": 16, "pose_hidden_dim": 32}
    )
    ckpt = save_checkpoint(tmp_path / "small.pt", model, step=7, training_data="unit-test renders")
    out = tmp_path / "small.onnx"
    runner = CliRunner()
    bad_values = (
        ("--pose-sigmas", "1.5"),
        ("--sigma-inflation", "2,3"),
        ("--sigma-inflation", "0"),
        ("--photo-sigma-scale", "-1"),
        ("--photo-sigma-scale", "1,x,2"),
    )
    for option, value in bad_values:
        bad = runner.invoke(app, ["export-onnx", str(ckpt), "-o", str(out), option, value])
        assert bad.exit_code == 2 and option in bad.output and "Traceback" not in bad.output
        assert not out.exists()
    good = runner.invoke(
        app,
        [
            "export-onnx",
            str(ckpt),
            "-o",
            str(out),
            "--pose-sigmas",
            "1.5,7,0.6",
            "--training-data",
            "26k renders",
            "--sigma-inflation",
            "37.8, 43.1,33.2",
            "--photo-sigma-scale",
            "1.5,1.2,1.25",
        ],
    )
    assert good.exit_code == 0, good.output
    metadata = FieldNetwork(out).metadata
    assert float(metadata["pose_sigma_rotation_deg"]) == 1.5
    assert float(metadata["pose_sigma_direction_deg"]) == 7.0
    assert float(metadata["pose_sigma_scale_rel"]) == 0.6
    assert metadata["training_data"] == "26k renders"
    assert metadata["sigma_inflation"] == "37.8,43.1,33.2"
    calibrator = Calibrator(out)
    assert calibrator.conf["refine"]["sigma_inflation"] == (37.8, 43.1, 33.2)
    assert metadata["photo_sigma_scale"] == "1.5,1.2,1.25"
    assert calibrator.photo_sigma_scale == (1.5, 1.2, 1.25)
    assert calibrator._learned_scale_sigma == 0.6
    assert calibrator.conf["fuse"]["prior_rotation_sigma_deg"] == 1.5
    assert calibrator.conf["fuse"]["prior_direction_sigma_deg"] == 7.0
    # a caller's own setting wins over the model's
    assert (
        Calibrator(out, conf={"fuse": {"prior_rotation_sigma_deg": 3.0}}).conf["fuse"][
            "prior_rotation_sigma_deg"
        ]
        == 3.0
    )


def test_mirrored_fields_map_back_exactly():
    """The mirrored image of a camera with gravity (gx, gy, gz) is a camera with gravity (-gx, gy, gz) and the
    principal point mirrored; its fields, mapped back cell for cell, are the original fields."""
    from stereogeo_cli.geometry import gravity_from_roll_pitch
    from stereogeo_cli.geometry.fields import latitude_at, up_at
    from stereogeo_cli.network.runtime import average_with_mirrored

    width, height, stride, focal = 288, 224, 4, 210.0
    x, y = cell_pixel_coordinates(height // stride, width // stride, stride)
    g = gravity_from_roll_pitch(np.radians(12.0), np.radians(-20.0))
    g_mirror = g * np.array([-1.0, 1.0, 1.0])
    cx, cy = width / 2, height / 2

    def fields(gravity, principal_x):
        up = up_at(gravity, focal, x, y, principal_x, cy).transpose(2, 0, 1)[None]
        lat = latitude_at(gravity, focal, x, y, principal_x, cy)[None]
        conf = np.random.default_rng(0).random(lat.shape)
        return {"up": up, "latitude": lat, "up_confidence": conf, "latitude_confidence": conf}

    plain, mirrored = fields(g, cx), fields(g_mirror, width - 1 - cx)
    mirrored["up_confidence"] = mirrored["latitude_confidence"] = plain["up_confidence"][..., ::-1]
    out = {f"{v}_{k}": a for v in ("left", "right") for k, a in plain.items()}
    out_mirrored = {f"{v}_{k}": a for v in ("left", "right") for k, a in mirrored.items()}
    merged = average_with_mirrored(out, out_mirrored)
    for key, value in out.items():
        np.testing.assert_allclose(merged[key], value, atol=1e-12, err_msg=key)


def test_flip_averaging_is_mirror_symmetric(exported):
    """With flip=True, calibrating a pair or its mirror image gives mirrored fields: the network's own
    left-right bias cancels out."""
    network = FieldNetwork(exported[0])
    rng = np.random.default_rng(3)
    size = (network.short_side, network.short_side + 64, 3)  # the network's own size: no resize, no crop
    left = rng.integers(0, 255, size, dtype=np.uint8)
    right = rng.integers(0, 255, size, dtype=np.uint8)
    out = network.predict(left, right, flip=True)
    mirror = network.predict(left[:, ::-1], right[:, ::-1], flip=True)
    for a, b in ((out.left, mirror.left), (out.right, mirror.right)):
        np.testing.assert_allclose(b.latitude[:, ::-1], a.latitude, atol=1e-5)
        np.testing.assert_allclose(b.up[:, ::-1] * np.array([-1.0, 1.0]), a.up, atol=1e-5)
        np.testing.assert_allclose(b.up_confidence[:, ::-1], a.up_confidence, atol=1e-5)
    plain = network.predict(left, right)
    assert not np.allclose(plain.left.latitude, out.left.latitude, atol=1e-5)  # flip did change something
    np.testing.assert_allclose(plain.translation, out.translation)  # the pose is the unmirrored run's


def test_a_blurring_model_exports_its_blur(tmp_path):
    torch.manual_seed(1)
    model = StereoGeoNet({"pretrained": False, "input_blur_px": 1.5}).eval()
    path = tmp_path / "blur.onnx"
    report = export_onnx(model, path, model_version="blur", training_data="none", parity_sizes=((64, 96),))
    assert max(report["max_abs_error"].values()) <= 1e-4
    assert '"input_blur_px": 1.5' in FieldNetwork(path, threads=1).metadata["model_conf"]
