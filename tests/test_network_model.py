"""StereoGeoNet in torch: pretrained encoder, output shapes and ranges, checkpoints."""

import math

import numpy as np
import pytest
import torch

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.geometry import pixel_grid
from stereogeo_cli.network.checkpoint import load_checkpoint, save_checkpoint
from stereogeo_cli.network.model import (
    OUTPUT_NAMES,
    EfficientNetLite0,
    StereoGeoNet,
    cell_coordinates,
    normalize_image,
    pretrained_lite0_path,
)
from stereogeo_cli.network.runtime import cell_pixel_coordinates

torch.set_num_threads(2)


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return StereoGeoNet().eval()


def test_pretrained_encoder_loads_every_key_and_matches_the_package_model():
    from efficientnet_lite_pytorch import EfficientNet

    encoder = EfficientNetLite0().eval()
    rest = encoder.load_pretrained()  # raises unless every parameter and buffer is matched
    assert set(rest) == {"_fc.weight", "_fc.bias"}
    reference = EfficientNet.from_pretrained(
        "efficientnet-lite0", weights_path=pretrained_lite0_path()
    ).eval()

    # A simple image: a bright disc on a dark background, plus a gradient (the package pads for 224 x 224).
    y, x = torch.meshgrid(torch.linspace(-1, 1, 224), torch.linspace(-1, 1, 224), indexing="ij")
    disc = ((x**2 + y**2) < 0.4).float()
    image = torch.stack([disc, 0.5 * (x + 1), 0.3 + 0.4 * disc * y.abs()])[None].clamp(0, 1)
    with torch.no_grad():
        ours = torch.nn.functional.linear(
            encoder(normalize_image(image))[0].mean(dim=(2, 3)), rest["_fc.weight"], rest["_fc.bias"]
        )
        theirs = reference(normalize_image(image))
    torch.testing.assert_close(ours, theirs, atol=1e-5, rtol=0)
    assert theirs.softmax(dim=1).max() > 0.05  # a peaked ImageNet prediction, not noise


def test_pretrained_weights_are_in_the_model(model):
    state = torch.load(pretrained_lite0_path(), map_location="cpu", weights_only=True)
    torch.testing.assert_close(
        model.encoder.blocks[15].project.conv.weight, state["_blocks.15._project_conv.weight"]
    )
    torch.testing.assert_close(model.encoder.head.bn.running_var, state["_bn1.running_var"])


@pytest.mark.parametrize("size_left, size_right", [((96, 128), (96, 128)), ((128, 64), (64, 160))])
def test_output_shapes_and_ranges(model, size_left, size_right):
    (h1, w1), (h2, w2) = size_left, size_right
    with torch.no_grad():
        out = model(torch.rand(2, 3, h1, w1), torch.rand(2, 3, h2, w2))
    assert tuple(out) == OUTPUT_NAMES
    for view, (h, w) in (("left", size_left), ("right", size_right)):
        assert out[f"{view}_up"].shape == (2, 2, h // 4, w // 4)
        for key in ("latitude", "up_confidence", "latitude_confidence"):
            assert out[f"{view}_{key}"].shape == (2, h // 4, w // 4)
        torch.testing.assert_close(out[f"{view}_up"].norm(dim=1), torch.ones(2, h // 4, w // 4))
        assert out[f"{view}_latitude"].abs().max() < math.pi / 2
        for key in ("up_confidence", "latitude_confidence"):
            assert 0 < out[f"{view}_{key}"].min() and out[f"{view}_{key}"].max() < 1
    assert out["quaternion"].shape == (2, 4) and out["translation"].shape == (2, 3)
    torch.testing.assert_close(out["quaternion"].norm(dim=1), torch.ones(2))
    assert (out["quaternion"][:, 0] >= 0).all()


def test_a_depth_head_adds_its_outputs_last_at_stride_8_and_leaves_the_rest():
    torch.manual_seed(0)
    plain = StereoGeoNet({"pretrained": False}).eval()
    torch.manual_seed(0)
    with_depth = StereoGeoNet({"pretrained": False, "depth_head": True}).eval()
    with_depth.load_state_dict(plain.state_dict(), strict=False)
    left, right = torch.rand(1, 3, 96, 128), torch.rand(1, 3, 128, 64)
    with torch.no_grad():
        a, b = plain(left, right), with_depth(left, right)
    assert tuple(b) == with_depth.output_names() and tuple(b)[: len(OUTPUT_NAMES)] == OUTPUT_NAMES
    assert b["left_depth"].shape == b["left_depth_spread"].shape == (1, 12, 16)
    assert b["right_depth"].shape == (1, 16, 8)
    for name in OUTPUT_NAMES:
        torch.testing.assert_close(a[name], b[name], rtol=0, atol=0)


def test_quaternion_sign_is_fixed_and_gradients_flow():
    model = StereoGeoNet({"pretrained": False}).train()
    with torch.no_grad():
        model.pose_head.mlp[-1].bias[:4] = torch.tensor([-1.0, 0.2, 0.0, 0.0])  # raw w < 0 must be flipped
    out = model(torch.rand(2, 3, 64, 96), torch.rand(2, 3, 96, 64))
    assert (out["quaternion"][:, 0] > 0).all()
    sum(v.mean() for v in out.values()).backward()
    for module in (model.encoder.stem.conv, model.decoder.lateral["4"].conv, model.up_head.out):
        assert module.weight.grad.abs().sum() > 0
    assert model.latitude_head.out.weight.grad.abs().sum() > 0
    assert model.pose_head.mlp[0].weight.grad.abs().sum() > 0
    assert model.pose_head.descriptor.weight.grad.abs().sum() > 0  # the soft matching is trained too


def test_pose_head_soft_matching_reads_a_known_displacement():
    """Right features = left features moved one stride-16 cell to the left: every left cell (but the first
    column) must find its match 16 px to the left, i.e. a displacement of -16 / (half short side)."""
    torch.manual_seed(0)
    model = StereoGeoNet({"pretrained": False, "pose_match_stride": 16, "pose_scale_votes": False}).eval()
    left = torch.randn(1, 112, 4, 6)
    right = torch.roll(left, shifts=-1, dims=3)
    with torch.no_grad():
        model.pose_head.log_temperature.fill_(math.log(50.0))
        corr = model.pose_head.correspondences(left, right)  # [1 x 24 x 9+context]
    moved = corr[0].reshape(4, 6, -1)[:, 1:]
    half_short = 4 * 16 / 2
    torch.testing.assert_close(moved[..., 4], torch.full((4, 5), -16 / half_short), atol=0.02, rtol=0)
    torch.testing.assert_close(moved[..., 5], torch.zeros(4, 5), atol=0.02, rtol=0)
    assert (moved[..., 8] > 0.99).all()  # peak cosine similarity of an exact match


def test_cell_coordinates_are_pixel_centre_correct():
    """Cell (i, j) at stride 4 is the mean of the pixel centres it covers: x = 4j + 1.5."""
    x, y = pixel_grid(24, 16)
    x_cells = x.reshape(4, 4, 6, 4).mean(axis=(1, 3))
    y_cells = y.reshape(4, 4, 6, 4).mean(axis=(1, 3))
    cx, cy = cell_pixel_coordinates(4, 6, 4)
    np.testing.assert_array_equal(cx, x_cells)
    np.testing.assert_array_equal(cy, y_cells)
    # The model's coordinate channels: the same centres relative to (W/2, H/2), over half the short side.
    coords = cell_coordinates(torch.zeros(1, 8, 4, 6), 4)[0].numpy()
    np.testing.assert_allclose(coords[0], (cx - 12) / 8, atol=1e-6)
    np.testing.assert_allclose(coords[1], (cy - 8) / 8, atol=1e-6)


def test_input_sides_must_be_multiples_of_32(model):
    with pytest.raises(ValueError, match="multiples of 32"):
        model(torch.rand(1, 3, 240, 320), torch.rand(1, 3, 224, 320))


def test_unknown_option_is_refused():
    with pytest.raises(ValueError, match="unknown"):
        StereoGeoNet({"decoder_width": 32, "pretrained": False})


def test_checkpoint_round_trip(tmp_path, model):
    path = save_checkpoint(tmp_path / "ckpt.pt", model, step=7, training_data="unit test")
    raw = torch.load(path, weights_only=True)
    assert raw["step"] == 7 and raw["conf"]["decoder_dim"] == model.conf["decoder_dim"]
    loaded, checkpoint = load_checkpoint(path)
    assert checkpoint["training_data"] == "unit test"
    images = torch.rand(1, 3, 64, 64), torch.rand(1, 3, 64, 96)
    with torch.no_grad():
        a, b = model(*images), loaded(*images)
    for name in OUTPUT_NAMES:
        torch.testing.assert_close(a[name], b[name])


def test_bad_checkpoints_raise_stereogeo_error(tmp_path):
    with pytest.raises(StereoGeoError, match="not found"):
        load_checkpoint(tmp_path / "missing.pt")
    (tmp_path / "junk.pt").write_bytes(b"\x00junk")
    with pytest.raises(StereoGeoError) as info:
        load_checkpoint(tmp_path / "junk.pt")
    assert info.value.exit_code == 2
    torch.save({"weights": 1}, tmp_path / "other.pt")
    with pytest.raises(StereoGeoError, match="not a stereogeo checkpoint"):
        load_checkpoint(tmp_path / "other.pt")


def test_pose_gradient_into_the_shared_encoder_is_scaled_and_the_outputs_are_not():
    torch.manual_seed(0)
    small = {"pretrained": False, "decoder_dim": 16, "head_dim": 8, "channels_last": False}
    full = StereoGeoNet({**small, "pose_encoder_grad": 1.0}).train()
    scaled = StereoGeoNet({**small, "pose_encoder_grad": 0.1}).train()
    scaled.load_state_dict(full.state_dict())
    left, right = torch.rand(2, 3, 64, 96), torch.rand(2, 3, 64, 96)
    grads, outs = [], []
    for model in (full, scaled):
        out = model(left, right)
        out["translation"].sum().backward()
        grads.append(model.encoder.stem.conv.weight.grad.clone())
        outs.append(out["translation"].detach())
    torch.testing.assert_close(outs[1], outs[0])
    # float32 sums in a different order: a tolerance relative to the largest gradient
    torch.testing.assert_close(grads[1], 0.1 * grads[0], rtol=1e-3, atol=1e-4 * float(grads[0].abs().max()))


V2 = {"pretrained": False, "pose_match_stride": 8, "pose_scale_votes": True}


def test_stride8_pose_head_shapes_and_gradients():
    """The stride-8 head: the same outputs; in training it also returns its soft matches (for the epipolar
    loss), and the gradient reaches its feature fusion, descriptors and per-cell MLP."""
    model = StereoGeoNet(V2).train()
    out = model(torch.rand(2, 3, 64, 96), torch.rand(2, 3, 64, 96))
    assert out["quaternion"].shape == (2, 4) and out["translation"].shape == (2, 3)
    xy_left, xy_right = out["pose_match_left"], out["pose_match_right"]
    assert xy_left.shape == xy_right.shape == (2, (64 // 8) * (96 // 8), 2)
    (out["translation"].norm(dim=1).log().sum() + out["quaternion"][:, 1:].sum()).backward()
    for module in (model.pose_head.fuse.conv, model.pose_head.descriptor, model.pose_head.point_mlp[0]):
        assert module.weight.grad.abs().sum() > 0
    with torch.no_grad():
        assert "pose_match_left" not in model.eval()(torch.rand(1, 3, 64, 96), torch.rand(1, 3, 64, 96))


def test_stride8_soft_matching_and_scale_votes_read_a_known_displacement():
    """Right descriptor inputs = left ones moved one stride-8 cell to the left: interior left cells find their
    match 8 px to the left. With constant votes and equal weights, |T| is exp(vote) times the geometric
    mean of the matched parallaxes (displacement minus a point at infinity's): the length follows the
    disparity."""
    torch.manual_seed(0)
    model = StereoGeoNet(V2).eval()
    head = model.pose_head
    channels = head.descriptor.in_channels
    left = torch.randn(1, channels, 6, 10)
    right = torch.roll(left, shifts=-1, dims=3)
    with torch.no_grad():
        head.log_temperature.fill_(math.log(50.0))
        corr = head.correspondences(left, right, torch.randn(1, head.context.conv.in_channels, 6, 10))
    moved = corr[0].reshape(6, 10, -1)[1:-1, 2:-1]  # away from the zero-padded borders and the wrap
    half_short = 6 * 8 / 2
    torch.testing.assert_close(
        moved[..., 4], torch.full_like(moved[..., 4], -8 / half_short), atol=0.02, rtol=0
    )
    torch.testing.assert_close(moved[..., 5], torch.zeros_like(moved[..., 5]), atol=0.02, rtol=0)

    with torch.no_grad():
        last = head.point_mlp[-1]
        last.weight[-2:] = 0.0  # votes: the bias; vote weights: all equal
        last.bias[-2:] = torch.tensor([math.log(3.0), 0.0])
        images = torch.rand(1, 3, 64, 96)
        fields, (mid, deep, fine) = model.forward_view(images)
        _, t, _, _ = head(mid, mid, deep, deep, fine, fine)
        reduced = head.reduce(deep)
        desc, context = head.match_features(fine, mid, reduced)
        displacement = head.correspondences(desc, desc, context)[0, :, 4:6]
    expected = 3.0 * torch.exp(torch.log(displacement.norm(dim=1) + 1e-3).mean())
    torch.testing.assert_close(t.norm(), expected, rtol=1e-4, atol=0)
    # The displacement of a point at infinity (here a set 0.1 to the right) is taken off before voting.
    with torch.no_grad():
        head.infinity.bias.copy_(torch.tensor([0.1, 0.0]))
        _, t, _, _ = head(mid, mid, deep, deep, fine, fine)
    parallax = displacement - torch.tensor([0.1, 0.0])
    torch.testing.assert_close(
        t.norm(), 3.0 * torch.exp(torch.log(parallax.norm(dim=1) + 1e-3).mean()), rtol=1e-4, atol=0
    )


def test_pose_scale_terms_make_up_the_length_of_t():
    """The diagnostic terms (benchmarks/pose_scale.py) are the forward pass's own: exp(Σ weight·(vote + log
    parallax)) is |T|, the weights sum to 1 and the matches are the epipolar loss's."""
    torch.manual_seed(1)
    model = StereoGeoNet(V2).eval()
    left, right = torch.rand(2, 3, 64, 96), torch.rand(2, 3, 64, 96)
    with torch.no_grad():
        t = model(left, right)["translation"]
        terms = model.pose_scale_terms(left, right)
    n_cells = (64 // 8) * (96 // 8)
    assert terms["weight"].shape == terms["vote"].shape == terms["log_parallax"].shape == (2, n_cells, 1)
    assert terms["left_xy"].shape == terms["right_xy"].shape == (2, n_cells, 2)
    torch.testing.assert_close(terms["weight"].sum(1), torch.ones(2, 1))
    length = torch.exp((terms["weight"] * (terms["vote"] + terms["log_parallax"])).sum((1, 2)))
    torch.testing.assert_close(length, t.norm(dim=1), rtol=1e-5, atol=0)
    with pytest.raises(ValueError, match="no votes"):
        StereoGeoNet({**V2, "pose_scale_votes": False}).eval().pose_scale_terms(left, right)


def test_checkpoints_from_before_the_stride8_head_still_load(tmp_path):
    """A checkpoint whose conf predates ``pose_match_stride`` and ``pose_scale_votes``: the stride-16 head."""
    from stereogeo_cli.network.checkpoint import load_checkpoint, save_checkpoint

    old = StereoGeoNet({"pretrained": False, "pose_match_stride": 16, "pose_scale_votes": False})
    path = save_checkpoint(tmp_path / "old.pt", old)
    checkpoint = torch.load(path, weights_only=True)
    del checkpoint["conf"]["pose_match_stride"], checkpoint["conf"]["pose_scale_votes"]
    torch.save(checkpoint, path)
    model, _ = load_checkpoint(path)
    assert model.pose_head.match_stride == 16 and not model.pose_head.scale_votes


def test_input_blur_is_a_normalised_gaussian_inside_the_graph():
    """``input_blur_px``: the network sees the image blurred by a fixed Gaussian (its sum 1, so flat areas
    keep their value), the same in training, export and inference; 0 leaves the image as it is."""
    from stereogeo_cli.network.model import gaussian_kernel

    kernel = gaussian_kernel(1.5)
    assert kernel.shape == (1, 1, 11, 11) and float(kernel.sum()) == pytest.approx(1.0, abs=1e-6)
    assert gaussian_kernel(0.0).numel() == 1
    torch.manual_seed(0)
    sharp = StereoGeoNet({"pretrained": False}).eval()
    blurred = StereoGeoNet({"pretrained": False, "input_blur_px": 1.5}).eval()
    blurred.load_state_dict(sharp.state_dict())  # the kernel is no weight: checkpoints stay as they were
    assert "blur_kernel" not in sharp.state_dict()
    image = torch.rand(1, 3, 64, 96)
    flat = torch.full((1, 3, 64, 96), 0.4)
    with torch.no_grad():
        # a flat image is the same blurred or not; a noisy one is not
        torch.testing.assert_close(blurred(flat, flat)["left_up"], sharp(flat, flat)["left_up"])
        assert not torch.allclose(blurred(image, image)["left_up"], sharp(image, image)["left_up"])
        import torch.nn.functional as F

        by_hand = F.conv2d(
            F.pad(image, (5, 5, 5, 5), mode="replicate"), kernel.expand(3, 1, -1, -1), groups=3
        )
        torch.testing.assert_close(blurred(image, image)["left_up"], sharp(by_hand, by_hand)["left_up"])
