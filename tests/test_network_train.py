"""Training: losses, resumable checkpoints, and two processes under torchrun holding identical replicas."""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from stereogeo_cli.geometry.epipolar import fundamental_matrix  # noqa: E402
from stereogeo_cli.network.data import (  # noqa: E402
    FolderPairs,
    SizedBatches,
    TrainingPairs,
    cover_crop,
    training_sample,
)
from stereogeo_cli.network.losses import ground_truth_fields  # noqa: E402
from stereogeo_cli.network.model import StereoGeoNet  # noqa: E402


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("data") / "train"
    from stereogeo_cli.synth.config import SynthConfig
    from stereogeo_cli.synth.dataset import make_dataset

    make_dataset(folder, 8, 5, SynthConfig(short_side=96), workers=1, progress=False)
    return folder


def _config(tmp_path: Path, data: Path, **changes) -> Path:
    conf = {
        "data": [str(data)], "out": str(tmp_path / "run"), "steps": 4, "batch_size": 2,
        "sizes": [[128, 96], [96, 128]], "warmup_steps": 1, "refiner_start": 2, "workers": 0,
        "log_every": 1, "threads": 1, "val_every": 1000, **changes,
    }  # fmt: skip
    path = tmp_path / "train.json"
    path.write_text(json.dumps(conf))
    return path


def test_training_sample_ground_truth_is_exact():
    """A cut image's latitude ground truth equals the latitude of the same ray in the original camera."""
    from stereogeo_cli.geometry import gravity_from_roll_pitch, intrinsic_matrix, latitude_at

    g = gravity_from_roll_pitch(0.2, -0.3)
    K = intrinsic_matrix(300.0, 640, 480)
    cam = {"K": K.tolist(), "gravity_up": g.tolist()}
    calib = {"left": cam, "right": cam, "R": np.eye(3).tolist(), "T": [-0.1, 0, 0]}
    image = np.zeros((480, 640, 3), np.uint8)
    sample = training_sample(image, image, calib, (192, 256))
    assert sample["left"].shape == (3, 256, 192)
    up, lat = ground_truth_fields(sample["gravity"][:1], sample["focal"][:1], 192, 256)
    rc = cover_crop(640, 480, 192, 256)
    ys, xs = np.mgrid[0:64, 0:48]
    cut = np.stack([4 * xs + 1.5, 4 * ys + 1.5], -1)
    orig = rc.points_to_input(cut)
    expected = latitude_at(g, 300.0, orig[..., 0], orig[..., 1], 320, 240)
    # the only difference is the half-pixel principal-point convention
    np.testing.assert_allclose(lat[0].numpy(), expected, atol=1.0 / sample["focal"][0].item())
    assert bool(sample["has_translation"]) and bool(sample["has_pose"])


def test_batches_are_split_across_ranks_and_resume_where_they_stopped():
    a = SizedBatches(100, 4, 3, seed=1, rank=0, world=2)
    b = SizedBatches(100, 4, 3, seed=1, rank=1, world=2)
    ia, ib = iter(a), iter(b)
    first = [next(ia) for _ in range(30)]
    other = [next(ib) for _ in range(12)]
    assert not {i for batch in first[:12] for i, *_ in batch} & {i for batch in other for i, *_ in batch}
    assert all(len({s for _, s, _ in batch}) == 1 for batch in first)  # one size per batch
    assert first[0][0][2] == 0 and first[29][0][2] == 29 // a.per_epoch  # items carry their epoch
    resumed = iter(SizedBatches(100, 4, 3, seed=1, rank=0, world=2, start_batch=17))
    assert [next(resumed) for _ in range(13)] == first[17:]


def _run_train(args, env=None):
    return subprocess.run(
        [sys.executable, "-m", "stereogeo_cli.network.train", *args],
        capture_output=True, text=True, env={**os.environ, **(env or {})}, timeout=600,
    )  # fmt: skip


def test_train_checkpoints_and_resumes_to_the_same_weights(tmp_path, tiny_dataset):
    config = _config(tmp_path, tiny_dataset)
    straight = _run_train(["--config", str(config), "--out", str(tmp_path / "straight")])
    assert straight.returncode == 0, straight.stderr
    first = _run_train(["--config", str(config), "--out", str(tmp_path / "split"), "--steps", "2"])
    assert first.returncode == 0, first.stderr
    second = _run_train(["--config", str(config), "--out", str(tmp_path / "split"), "--resume"])
    assert second.returncode == 0, second.stderr
    assert "[resume] step=2" in second.stderr
    a = torch.load(tmp_path / "straight" / "latest.pt", weights_only=True)
    b = torch.load(tmp_path / "split" / "latest.pt", weights_only=True)
    assert a["step"] == b["step"] == 4
    for key, value in a["model"].items():
        torch.testing.assert_close(b["model"][key], value, atol=1e-5, rtol=1e-4, msg=key)
    assert "optimizer" in a and a["input_short_side"] == 224
    log = [json.loads(line) for line in (tmp_path / "straight" / "log.jsonl").read_text().splitlines()]
    assert any(r["event"] == "train" and "camera" in r for r in log)  # the refiner loss ran


def test_two_processes_under_torchrun_hold_identical_replicas(tmp_path, tiny_dataset):
    config = _config(tmp_path, tiny_dataset, steps=2, batch_size=1)
    replicas = tmp_path / "replicas"
    replicas.mkdir()
    result = subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--master_port", "29533",
         "-m", "stereogeo_cli.network.train", "--config", str(config), "--dump-replica", str(replicas)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-3000:]
    a = torch.load(replicas / "rank0.pt", weights_only=True)
    b = torch.load(replicas / "rank1.pt", weights_only=True)
    for key, value in a.items():
        assert torch.equal(value, b[key]), key
    start = json.loads((tmp_path / "run" / "log.jsonl").read_text().splitlines()[0])
    assert start["world"] == 2


def test_grey_share_greys_that_share_of_pairs_both_views_alike_and_reproducibly(tiny_dataset):
    source = FolderPairs(tiny_dataset)
    colour = TrainingPairs([source], [(96, 96)])
    grey = TrainingPairs([source], [(96, 96)], grey_share=0.5, seed=3)
    every = TrainingPairs([source], [(96, 96)], grey_share=1.0, seed=3)

    def is_grey(sample):
        return all(bool((sample[v][0] == sample[v][1]).all() and (sample[v][1] == sample[v][2]).all())
                   for v in ("left", "right"))  # fmt: skip

    items = [(i, 0, epoch) for epoch in range(4) for i in range(len(source))]
    assert not any(is_grey(colour[item]) for item in items)  # renders are colour
    assert all(is_grey(every[item]) for item in items)
    flags = [is_grey(grey[item]) for item in items]
    assert 0.2 < np.mean(flags) < 0.8
    assert flags == [is_grey(grey[item]) for item in items]  # reproducible
    per_epoch = np.reshape(flags, (4, len(source)))
    assert (per_epoch != per_epoch[0]).any()  # and drawn again each epoch
    # a grey pair keeps its ground truth and its luma
    sample, reference = every[(0, 0, 0)], colour[(0, 0, 0)]
    assert torch.equal(sample["focal"], reference["focal"]) and torch.equal(sample["R"], reference["R"])
    luma = reference["left"].mul(255).round().permute(1, 2, 0).numpy().astype(np.uint8)
    expected = cv2.cvtColor(luma, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    np.testing.assert_allclose(sample["left"][0].numpy(), expected, atol=2.5 / 255)


def _detail(image: torch.Tensor) -> float:
    """Mean absolute difference of vertically adjacent pixels: falls with blur, rises with sharpening."""
    return float((image[:, 1:] - image[:, :-1]).abs().mean())


def test_sharpness_share_blurs_or_sharpens_that_share_of_pairs_both_views_alike(tiny_dataset):
    source = FolderPairs(tiny_dataset)
    plain = TrainingPairs([source], [(96, 96)])
    changed = TrainingPairs([source], [(96, 96)], seed=3, sharpness_share=0.6)
    items = [(i, 0, epoch) for epoch in range(6) for i in range(len(source))]
    ratios = []
    for item in items:
        sample, reference = changed[item], plain[item]
        for key in ("focal", "gravity", "R", "T"):
            assert torch.equal(sample[key], reference[key]), key  # the ground truth is the cut's
        ratios.append([_detail(sample[v]) / _detail(reference[v]) for v in ("left", "right")])
        assert sample["left"].min() >= 0 and sample["left"].max() <= 1
    ratios = np.array(ratios)
    blurred, sharpened = (ratios < 0.95).all(axis=1), (ratios > 1.05).all(axis=1)
    untouched = np.isclose(ratios, 1.0).all(axis=1)
    # every pair is either left alone or changed the same way in both views
    assert (blurred | sharpened | untouched).all()
    assert 0.3 < np.mean(~untouched) < 0.9 and blurred.any() and sharpened.any()
    again = [changed[item] for item in items[:8]]
    assert all(
        torch.equal(a["left"], changed[item]["left"]) for a, item in zip(again, items[:8], strict=True)
    )
    per_epoch = untouched.reshape(6, len(source))
    assert (per_epoch != per_epoch[0]).any()  # drawn again each epoch
    # off by default: the renders as they are
    assert torch.equal(TrainingPairs([source], [(96, 96)], seed=3)[items[0]]["left"], plain[items[0]]["left"])


def test_sharpness_share_outside_0_to_1_is_a_clear_error(tmp_path, tiny_dataset):
    result = _run_train(["--config", str(_config(tmp_path, tiny_dataset)), "--sharpness-share", "-0.1"])
    assert result.returncode == 2
    assert "sharpness_share must be between 0 and 1" in result.stderr and "Traceback" not in result.stderr


def test_grey_share_outside_0_to_1_is_a_clear_error(tmp_path, tiny_dataset):
    result = _run_train(["--config", str(_config(tmp_path, tiny_dataset)), "--grey-share", "1.5"])
    assert result.returncode == 2
    assert "grey_share must be between 0 and 1" in result.stderr and "Traceback" not in result.stderr


def test_unknown_data_folder_is_a_clear_error(tmp_path):
    result = _run_train(["--data", str(tmp_path / "missing"), "--out", str(tmp_path / "o"), "--steps", "1"])
    assert result.returncode == 2
    assert "is not a dataset folder" in result.stderr and "Traceback" not in result.stderr


def test_init_takes_every_matching_weight_across_a_change_of_architecture(tmp_path):
    """Fine-tuning after a head changed: the encoder, decoder and field heads come from the checkpoint, the
    changed head stays fresh, and the caller learns which parameters those are."""
    import torch

    from stereogeo_cli.errors import StereoGeoError
    from stereogeo_cli.network.checkpoint import init_from_checkpoint, save_checkpoint
    from stereogeo_cli.network.model import StereoGeoNet

    small = {"pretrained": False, "decoder_dim": 16, "head_dim": 8, "pose_hidden_dim": 32}
    torch.manual_seed(1)
    old = StereoGeoNet({**small, "pose_reduce_dim": 16})
    ckpt = save_checkpoint(tmp_path / "old.pt", old, step=1, training_data="unit")
    torch.manual_seed(2)
    new = StereoGeoNet({**small, "pose_reduce_dim": 24})
    fresh = init_from_checkpoint(new, ckpt)
    assert fresh and all(name.startswith("pose_head.") for name in fresh)
    assert "pose_head.reduce.conv.weight" in fresh and "pose_head.descriptor.weight" not in fresh
    new_state, old_state = new.state_dict(), old.state_dict()
    for name in ("encoder.stem.conv.weight", "decoder.lateral.4.conv.weight", "up_head.out.weight"):
        torch.testing.assert_close(new_state[name], old_state[name])
    torch.save({"model": {"nothing.like.it": torch.zeros(1)}}, tmp_path / "other.pt")
    with pytest.raises(StereoGeoError, match="shares no weights"):
        init_from_checkpoint(new, tmp_path / "other.pt")


def test_training_only_the_pose_head_leaves_every_field_weight_and_statistic_alone(tmp_path, tiny_dataset):
    """``train_only: ["pose_head"]``: the encoder, decoder and field heads (batch-norm statistics included)
    come out bit-identical, so the fields of the fine-tuned model are the initial model's; the pose head
    learns, with the epipolar loss on its soft matches."""
    from stereogeo_cli.network.checkpoint import save_checkpoint
    from stereogeo_cli.network.model import StereoGeoNet

    torch.manual_seed(3)
    init = save_checkpoint(tmp_path / "init.pt", StereoGeoNet({"pretrained": False}), training_data="unit")
    config = _config(
        tmp_path, tiny_dataset, steps=3, init=str(init), train_only=["pose_head"],
        loss={"epipolar_weight": 1.0, "camera_weight": 0.0},
    )  # fmt: skip
    result = _run_train(["--config", str(config)])
    assert result.returncode == 0, result.stderr
    before = torch.load(init, weights_only=True)["model"]
    after = torch.load(tmp_path / "run" / "latest.pt", weights_only=True)["model"]
    moved = {k for k in before if not torch.equal(before[k], after[k])}
    assert moved and all(k.startswith("pose_head.") for k in moved), sorted(moved)[:5]
    assert "pose_head.descriptor.weight" in moved
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert any(r["event"] == "train" and r.get("epipolar", 0) > 0 for r in log)


def test_epipolar_loss_vanishes_on_true_matches_and_grows_across_the_epipolar_lines():
    from stereogeo_cli.geometry import rotation_from_axis_angle
    from stereogeo_cli.network.losses import epipolar_loss

    rng = np.random.default_rng(0)
    R = rotation_from_axis_angle(np.radians([0.5, 3.0, -1.0]))
    T = np.array([-0.3, 0.01, 0.02])
    focal, half_short = np.array([110.0, 95.0]), 48.0  # a 128 x 96 image
    X = np.c_[rng.uniform(-2, 2, (200, 2)), rng.uniform(2, 10, 200)]
    points = []
    for P, f in ((X, focal[0]), (X @ R.T + T, focal[1])):
        points.append(P[:, :2] / P[:, 2:] * f / half_short)  # relative to the centre, / half short side
    as_t = [torch.tensor(a, dtype=torch.float64)[None] for a in (*points, focal, R, T)]
    exact = epipolar_loss(*as_t[:2], as_t[2], as_t[3], as_t[4], half_short, 0.03)
    assert float(exact) < 1e-9
    # 3 px across the (near-horizontal) epipolar lines in one image: the Sampson distance shares the
    # correction between both images, about 3/√2 px, so each term is near log(1 + (2.1/48 / 0.03)²) ≈ 1.15
    # (the two focal lengths differ by 15 %: the share is not exactly a half).
    shift = torch.tensor([0.0, 3 / half_short])
    across = epipolar_loss(as_t[0], as_t[1] + shift, *as_t[2:5], half_short, 0.03)
    assert 1.0 < float(across) < 1.45
    along = epipolar_loss(
        as_t[0], as_t[1] + torch.tensor([3 / half_short, 0.0]), *as_t[2:5], half_short, 0.03
    )
    assert float(along) < 0.1


def test_epipolar_loss_measures_the_fusions_sampson_distance():
    """The training loss's distance is the fusion's Sampson error (fuse.sampson_errors, pixels) in units of
    half the short side: one formula, two homes (torch for gradients, NumPy for the product)."""
    from stereogeo_cli.fuse import sampson_errors
    from stereogeo_cli.geometry import fundamental_matrix, rotation_from_axis_angle
    from stereogeo_cli.network.losses import epipolar_loss

    rng = np.random.default_rng(1)
    R, T = rotation_from_axis_angle(np.radians([1.0, -2.0, 0.5])), np.array([-0.2, 0.02, -0.01])
    focal, half_short, scale = np.array([150.0, 120.0]), 64.0, 0.03
    xy_left, xy_right = rng.uniform(-1, 1, (1, 40, 2)), rng.uniform(-1, 1, (1, 40, 2))
    K = [np.diag([f, f, 1.0]) for f in focal]  # centred principal point: pixels relative to the centre
    d = sampson_errors(
        fundamental_matrix(K[0], K[1], R, T), xy_left[0] * half_short, xy_right[0] * half_short
    )
    expected = np.mean(np.log1p((d / (half_short * scale)) ** 2))
    as_t = [torch.tensor(a, dtype=torch.float64) for a in (xy_left, xy_right, focal[None], R[None], T[None])]
    np.testing.assert_allclose(float(epipolar_loss(*as_t, half_short, scale)), expected, rtol=1e-9)


def _bilinear(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return np.stack([cv2.remap(image, *np.float32(xy[None].transpose(2, 0, 1)), cv2.INTER_LINEAR)[0]])[0]


@pytest.fixture(scope="module")
def depth_pair():
    """A rendered pair with depth maps and a baseline (no photometric augmentation, so that a surface looks
    the same in both views)."""
    from stereogeo_cli.synth.config import SynthConfig
    from stereogeo_cli.synth.sample import sample_pair

    cfg = SynthConfig(short_side=192, depth=True, augment=0.0, texture_size=128, texture_layers=24)
    for index in range(20):
        sample = sample_pair(11, index, cfg)
        if np.linalg.norm(sample.calib["T"]) > 0.1 and (sample.depth_left > 0).mean() > 0.9:
            return sample
    raise AssertionError("no rendered pair with a baseline and little sky in 20 draws")


def test_match_targets_land_on_the_same_surface(depth_pair):
    """The true right position of each left cell (from the depth maps) shows what the left cell shows: small
    patches agree there far better than two cells off, and the positions lie on the true epipolar lines."""
    s = depth_pair
    sample = training_sample(s.left, s.right, s.calib, (224, 160), (s.depth_left, s.depth_right))
    valid = sample["match_valid"].numpy()
    assert valid.mean() > 0.5
    half, offset = 80.0, np.array([112.0, 80.0])
    cols, rows = np.meshgrid(np.arange(224 // 8), np.arange(160 // 8))
    left_px = np.stack([cols * 8 + 3.5, rows * 8 + 3.5], -1).reshape(-1, 2)[valid]
    right_px = sample["match_xy"].numpy()[valid] * half + offset
    left_img = cv2.blur(sample["left"].numpy().transpose(1, 2, 0), (3, 3))
    right_img = cv2.blur(sample["right"].numpy().transpose(1, 2, 0), (3, 3))
    at_left = _bilinear(left_img, left_px)
    here = np.abs(_bilinear(right_img, right_px) - at_left).mean(-1)
    off = np.abs(_bilinear(right_img, right_px + [16.0, 0.0]) - at_left).mean(-1)
    assert np.median(here) < 0.02 and np.median(here) < 0.3 * np.median(off)
    # on the true epipolar lines (the cut keeps a centred pinhole: K from the cut's focal)
    f_left, f_right = sample["focal"].numpy()
    K1 = np.array([[f_left, 0, 112], [0, f_left, 80], [0, 0, 1.0]])
    K2 = np.array([[f_right, 0, 112], [0, f_right, 80], [0, 0, 1.0]])
    F = fundamental_matrix(K1, K2, sample["R"].numpy().astype(float), sample["T"].numpy().astype(float))
    lines = np.c_[left_px - 0.5, np.ones(len(left_px))] @ F.T
    d = np.abs(np.sum(np.c_[right_px - 0.5, np.ones(len(left_px))] * lines, 1)) / np.hypot(*lines[:, :2].T)
    assert np.percentile(d, 95) < 0.05


def test_match_losses_vanish_at_the_truth_and_grow_away_from_it(depth_pair):
    from stereogeo_cli.network.losses import match_losses

    s = depth_pair
    one = training_sample(s.left, s.right, s.calib, (224, 160), (s.depth_left, s.depth_right))
    batch = {k: v[None] for k, v in one.items()}
    cols, rows = np.meshgrid(np.arange(28), np.arange(20))
    left_xy = (np.stack([cols * 8 + 3.5, rows * 8 + 3.5], -1).reshape(1, -1, 2) - [112, 80]) / 80
    left_xy = torch.tensor(left_xy, dtype=torch.float32)
    parallax = (batch["match_xy"] - batch["infinity_xy"]).norm(dim=-1, keepdim=True)
    truth = {
        "pose_match_left": left_xy,
        "pose_match_right": batch["match_xy"].clone(),
        "pose_infinity": (batch["infinity_xy"] - left_xy).mean(1),
        "pose_vote": torch.log(batch["T"].norm()) - torch.log(parallax + 1e-3),
    }
    conf = {"match_weight": 1.0, "vote_weight": 1.0, "infinity_weight": 1.0, "match_scale": 0.03,
            "vote_min_parallax": 0.02, "vote_beta": 0.1, "infinity_beta": 0.01}  # fmt: skip
    at_truth = match_losses(truth, batch, conf)
    assert set(at_truth) == {"match", "vote", "infinity"}
    for value in at_truth.values():
        assert float(value) < 1e-6
    moved = {k: v + 0.05 for k, v in truth.items()}
    for name, value in match_losses(moved, batch, conf).items():
        assert float(value) > 1e-3, name
    coarse = {**truth, "pose_match_left": left_xy[:, ::4]}  # a stride-16 head's cells
    with pytest.raises(ValueError, match="stride-8"):
        match_losses(coarse, batch, conf)
    no_depth = training_sample(s.left, s.right, s.calib, (224, 160))
    assert not no_depth["match_valid"].any()
    assert torch.equal(no_depth["infinity_xy"], one["infinity_xy"])


def test_training_on_depth_maps_runs_the_match_losses_and_leaves_the_frozen_parts(tmp_path):
    """A dataset made with --depth feeds the pose head's match, vote and point-at-infinity losses; with
    ``train_only: [pose_head]`` the fields' weights do not move."""
    from stereogeo_cli.synth.config import SynthConfig
    from stereogeo_cli.synth.dataset import make_dataset

    data = tmp_path / "depth"
    make_dataset(data, 4, 5, SynthConfig(short_side=96, depth=True), workers=1, progress=False)
    config = _config(
        tmp_path, data, steps=2, train_only=["pose_head"], refiner_start=0,
        loss={"match_weight": 1.0, "vote_weight": 1.0, "infinity_weight": 1.0, "epipolar_weight": 1.0},
    )  # fmt: skip
    first = _run_train(["--config", str(config), "--steps", "1", "--out", str(tmp_path / "one")])
    assert first.returncode == 0, first.stderr
    run = _run_train(["--config", str(config), "--init", str(tmp_path / "one" / "latest.pt")])
    assert run.returncode == 0, run.stderr
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    trained = [r for r in log if r["event"] == "train"]
    assert trained and all(np.isfinite(r[k]) for r in trained for k in ("match", "infinity"))
    a = torch.load(tmp_path / "one" / "latest.pt", weights_only=True)["model"]
    b = torch.load(tmp_path / "run" / "latest.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a if not k.startswith("pose_head"))
    assert any(not torch.equal(a[k], b[k]) for k in a if k.startswith("pose_head"))


def test_depth_targets_are_each_cells_log_depth_over_focal(depth_pair):
    from stereogeo_cli.network.data import depth_targets

    s = depth_pair
    sample = training_sample(s.left, s.right, s.calib, (224, 160), (s.depth_left, s.depth_right))
    q = sample["depth_left"].numpy()
    assert q.shape == (160 // 8, 224 // 8)
    assert np.isfinite(q).mean() > 0.8
    # back to metres at each cell centre, against the depth map read there directly
    rc = cover_crop(s.left.shape[1], s.left.shape[0], 224, 160)
    focal_n = float(sample["focal"][0]) / 80.0
    cols, rows = np.meshgrid(np.arange(28), np.arange(20))
    centres = rc.points_to_input(np.stack([cols * 8 + 3.5, rows * 8 + 3.5], -1).reshape(-1, 2))
    ij = np.rint(centres).astype(int)
    z = s.depth_left[ij[:, 1].clip(0, s.depth_left.shape[0] - 1), ij[:, 0].clip(0, s.depth_left.shape[1] - 1)]
    valid = np.isfinite(q.ravel()) & (z > 0)
    ratio = np.exp(q.ravel()[valid]) * focal_n / z[valid]
    assert np.median(np.abs(np.log(ratio))) < 0.03  # a cell's median against its centre pixel
    # sky: no target; no depth map: no target at all
    sky = np.zeros_like(s.depth_left)
    assert np.isnan(depth_targets(sky, rc, float(sample["focal"][0]))).all()
    assert np.isnan(training_sample(s.left, s.right, s.calib, (224, 160))["depth_left"].numpy()).all()


def test_depth_loss_is_least_at_the_truth_with_the_right_spread(depth_pair):
    from stereogeo_cli.network.losses import compute_losses

    s = depth_pair
    one = training_sample(s.left, s.right, s.calib, (224, 160), (s.depth_left, s.depth_right))
    batch = {k: v[None] for k, v in one.items()}
    with torch.no_grad():
        out = StereoGeoNet({"pretrained": False, "depth_head": True}).eval()(batch["left"], batch["right"])

    def loss(shift, log_spread):
        moved = dict(out)
        for view in ("left", "right"):
            truth = torch.nan_to_num(batch[f"depth_{view}"])
            moved[f"{view}_depth"] = truth + shift
            moved[f"{view}_depth_spread"] = torch.full_like(truth, log_spread)
        zero = {k: 0.0 for k in ("up_weight", "latitude_weight", "confidence_weight", "camera_weight",
                                  "rotation_weight", "translation_weight", "epipolar_weight")}  # fmt: skip
        return float(compute_losses(moved, batch, {**zero, "depth_weight": 1.0}, with_refiner=False)["depth"])

    assert loss(0.0, -3.0) < loss(0.2, -3.0) < loss(0.5, -3.0)
    plain = {k: v for k, v in out.items() if "depth" not in k}  # a model without the head: a clear error
    with pytest.raises(ValueError, match="depth_head"):
        compute_losses(plain, batch, {"depth_weight": 1.0}, with_refiner=False)
    # with errors of 0.2, the spread that is best is about 0.2 (a Laplace scale)
    assert loss(0.2, np.log(0.2)) < min(loss(0.2, np.log(0.05)), loss(0.2, np.log(0.8)))


def test_training_the_depth_head_alone_leaves_the_rest_of_the_model(tmp_path):
    from stereogeo_cli.synth.config import SynthConfig
    from stereogeo_cli.synth.dataset import make_dataset

    data = tmp_path / "depth"
    make_dataset(data, 4, 5, SynthConfig(short_side=96, depth=True), workers=1, progress=False)
    zero = {k: 0.0 for k in ("up_weight", "latitude_weight", "confidence_weight", "rotation_weight",
                              "translation_weight")}  # fmt: skip
    common = {
        "train_only": ["depth_head"],
        "model": {"depth_head": True},
        "loss": {**zero, "depth_weight": 1.0},
    }
    no_head = _run_train(["--config", str(_config(tmp_path, data, steps=1, loss=common["loss"]))])
    assert no_head.returncode == 2 and "depth head" in no_head.stderr and "Traceback" not in no_head.stderr
    first = _run_train(
        ["--config", str(_config(tmp_path, data, steps=1, out=str(tmp_path / "one"), **common))]
    )
    assert first.returncode == 0, first.stderr
    run = _run_train(
        [
            "--config",
            str(_config(tmp_path, data, steps=2, init=str(tmp_path / "one" / "latest.pt"), **common)),
        ]
    )
    assert run.returncode == 0, run.stderr
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    assert all(np.isfinite(r["depth"]) for r in log if r["event"] == "train")
    a = torch.load(tmp_path / "one" / "latest.pt", weights_only=True)["model"]
    b = torch.load(tmp_path / "run" / "latest.pt", weights_only=True)["model"]
    assert all(torch.equal(a[k], b[k]) for k in a if not k.startswith("depth_head"))
    assert any(not torch.equal(a[k], b[k]) for k in a if k.startswith("depth_head"))


def test_teacher_loss_holds_the_fields_of_the_masked_pairs_only():
    """The distillation term: zero where the student's fields are the teacher's, the L1 of the up vectors
    plus twice the latitudes' where they are not, and blind to the pairs outside the mask."""
    from stereogeo_cli.network.losses import teacher_loss

    g = torch.Generator().manual_seed(4)
    out = {}
    for view in ("left", "right"):
        up = torch.randn(3, 2, 6, 8, generator=g)
        out[f"{view}_up"] = up / up.norm(dim=1, keepdim=True)
        out[f"{view}_latitude"] = torch.rand(3, 6, 8, generator=g) - 0.5
    mask = torch.tensor([False, True, False])
    held = {k: v.clone() for k, v in out.items()}
    assert float(teacher_loss(out, held, mask)) == 0.0
    moved = {k: v.clone() for k, v in out.items()}
    moved["left_latitude"][1] += 0.01  # a masked pair: 2 × 0.01 on the left view, averaged over 2 views
    assert float(teacher_loss(moved, held, mask)) == pytest.approx(0.01, rel=1e-5)
    moved = {k: v.clone() for k, v in out.items()}
    moved["left_latitude"][0] += 0.3  # a pair outside the mask
    moved["right_up"][2] *= -1.0
    assert float(teacher_loss(moved, held, mask)) == 0.0
    empty = teacher_loss(moved, held, torch.zeros(3, dtype=torch.bool))
    assert float(empty) == 0.0


def test_training_with_a_teacher_starts_in_agreement_with_it(tmp_path, tiny_dataset):
    """A fine-tune held to its own starting point: before the first step the student's fields are the
    teacher's exactly (the same batch-norm modes), so the first logged distillation loss is 0, and it grows
    as the student moves. Without a teacher checkpoint the setting is a one-line error."""
    import shutil

    from stereogeo_cli.network.checkpoint import save_checkpoint

    data = tmp_path / "mixed"
    shutil.copytree(tiny_dataset, data)
    records = [json.loads(line) for line in (data / "calib.jsonl").read_text().splitlines()]
    for record in records[::2]:  # half the pairs as pure rotations, as the panorama crops are
        record["T"] = [0.0, 0.0, 0.0]
    (data / "calib.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    torch.manual_seed(5)
    init = save_checkpoint(tmp_path / "init.pt", StereoGeoNet({"pretrained": False}), training_data="unit")
    loss = {"teacher_weight": 4.0, "rotation_weight": 0.0, "translation_weight": 0.0}
    common = {"init": str(init), "train_only": ["decoder", "up_head", "latitude_head"], "loss": loss}
    missing = _run_train(["--config", str(_config(tmp_path, data, steps=1, **common))])
    assert missing.returncode == 2 and "teacher" in missing.stderr and "Traceback" not in missing.stderr
    run = _run_train(
        [
            "--config",
            str(_config(tmp_path, data, steps=4, batch_size=4, teacher=str(init), lr=1e-3, **common)),
        ]
    )
    assert run.returncode == 0, run.stderr
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    held = [r["teacher"] for r in log if r["event"] == "train"]
    assert len(held) == 4 and held[0] < 1e-6 and max(held[1:]) > 1e-4, held
    # A resumed run must keep its teacher: a changed file (say the model it was fine-tuning from, replaced
    # by this run's result) is a one-line error, not a silent change of the loss.
    torch.manual_seed(7)
    save_checkpoint(init, StereoGeoNet({"pretrained": False}), training_data="another")
    config = _config(tmp_path, data, steps=6, batch_size=4, teacher=str(init), lr=1e-3, **common)
    changed = _run_train(["--config", str(config), "--resume"])
    assert changed.returncode == 2 and "Traceback" not in changed.stderr
    assert "is not the file this run started with" in changed.stderr
    assert len(changed.stderr.strip().splitlines()[-1]) < 300


def test_wide_batches_draw_only_from_the_wide_pool_at_its_share_and_resume():
    """Wide frames (indices 80–99) fill their share of the batches, at wide sizes (indices 3–4), and never
    an ordinary batch; ranks stay disjoint and a resumed stream is the same stream."""
    a = SizedBatches(100, 4, 3, seed=2, rank=0, world=2, wide=(80, 2, 0.4))
    b = SizedBatches(100, 4, 3, seed=2, rank=1, world=2, wide=(80, 2, 0.4))
    epoch = a.epoch_batches(0)
    assert len(epoch) == a.per_epoch and a.n_ordinary == 20 and a.n_wide == 14  # 20 × 0.4 / 0.6, even
    wide = [batch for batch in epoch if batch[0][1] >= 3]
    for batch in epoch:
        is_wide = batch[0][1] >= 3
        assert len({s for _, s, _ in batch}) == 1 and batch[0][1] < 5
        assert all((i >= 80) == is_wide for i, _, _ in batch)
    assert 0 < len(wide) < len(epoch)
    assert not {i for x in epoch if x[0][1] < 3 for i, *_ in x} & {
        i for x in b.epoch_batches(0) if x[0][1] < 3 for i, *_ in x
    }
    ia = iter(a)
    first = [next(ia) for _ in range(40)]
    resumed = iter(SizedBatches(100, 4, 3, seed=2, rank=0, world=2, start_batch=23, wide=(80, 2, 0.4)))
    assert [next(resumed) for _ in range(17)] == first[23:]
    # without wide frames the stream is the one every earlier run saw
    plain = SizedBatches(100, 4, 3, seed=1)
    rng = np.random.default_rng([1, 0])
    order, sizes = rng.permutation(100)[:100], rng.integers(3, size=25)
    assert plain.epoch_batches(0)[3] == [(int(i), int(sizes[3]), 0) for i in order[12:16]]


def test_training_with_wide_frames_cuts_their_batches_to_wide_sizes(tmp_path, tiny_dataset):
    """A run with wide_data trains on both pools at the sampler's share, the teacher sitting out the wide
    batches, and records the wide data in the checkpoint; a wide_share of 1 is a one-line error."""
    from stereogeo_cli.network.checkpoint import save_checkpoint
    from stereogeo_cli.synth.config import SynthConfig
    from stereogeo_cli.synth.dataset import make_dataset

    wide = tmp_path / "wide"
    make_dataset(wide, 6, 9, SynthConfig(short_side=64, aspects=(3.0,), portrait_share=0.0), workers=1,
                 progress=False)  # fmt: skip
    assert cv2.imread(str(wide / "left" / "000000.png")).shape[:2] == (64, 192)
    # Every wide pair a pure rotation, every ordinary pair not: a teacher run on a wide batch would show.
    records = [json.loads(line) for line in (wide / "calib.jsonl").read_text().splitlines()]
    (wide / "calib.jsonl").write_text(
        "".join(json.dumps({**r, "T": [0.0, 0.0, 0.0]}) + "\n" for r in records)
    )
    torch.manual_seed(6)
    init = save_checkpoint(tmp_path / "init.pt", StereoGeoNet({"pretrained": False}), training_data="unit")
    common = {
        "wide_data": [str(wide)], "wide_sizes": [[192, 64]], "wide_share": 0.5, "init": str(init),
        "teacher": str(init), "train_only": ["decoder", "up_head", "latitude_head"], "lr": 1e-3,
        "loss": {"teacher_weight": 4.0, "rotation_weight": 0.0, "translation_weight": 0.0},
    }  # fmt: skip
    bad = _run_train(["--config", str(_config(tmp_path, tiny_dataset, **common)), "--wide-share", "1"])
    assert bad.returncode == 2 and "wide_share" in bad.stderr and "Traceback" not in bad.stderr
    run = _run_train(["--config", str(_config(tmp_path, tiny_dataset, steps=8, **common))])
    assert run.returncode == 0, run.stderr
    log = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    steps = [r for r in log if r["event"] == "train"]
    sampler = SizedBatches(14, 2, 2, seed=0, wide=(8, 1, 0.5))
    draw = [batch[0][1] == 2 for _ in range(2) for batch in sampler.epoch_batches(_)][:8]
    assert [r["wide_batches"] for r in steps] == list(np.cumsum(draw)) and 0 < sum(draw) < 8
    assert all(r["teacher"] == 0.0 for r in steps)
    saved = torch.load(tmp_path / "run" / "latest.pt", weights_only=True)
    assert f"{wide} (wide)" in saved["training_data"]


def test_render_config_sets_the_on_the_fly_pairs_sampler_and_refuses_unknown_settings(tmp_path):
    from stereogeo_cli.errors import StereoGeoError
    from stereogeo_cli.network.train import _sources, default_conf

    conf = {
        **default_conf, "render": 5, "render_seed": 7,
        "render_config": {"vfov_deg": [18, 40], "aspects": [2.0], "panorama_max_upsampling": 3.5},
    }  # fmt: skip
    (source,) = _sources(conf)
    assert source.config.vfov_deg == (18, 40) and source.config.aspects == (2.0,)
    assert source.config.panorama_max_upsampling == 3.5
    _, _, calib = source[0]  # rendered with those settings: a 2:1 frame, vFoV within 18–40°
    w, h, f = calib["left"]["width"], calib["left"]["height"], calib["left"]["K"][1][1]
    assert w == 2 * h and 18 - 1e-6 <= np.degrees(2 * np.arctan(h / (2 * f))) <= 40 + 1e-6
    with pytest.raises(StereoGeoError, match="unknown render_config settings: \\['vfov'\\]"):
        _sources({**conf, "render_config": {"vfov": [18, 40]}})


@pytest.mark.parametrize("device, message", [("gpu", "is not a torch device"), ("cuda", "sees no CUDA GPU")])
def test_a_device_that_is_not_there_is_a_clear_error(tmp_path, tiny_dataset, device, message):
    if device == "cuda" and torch.cuda.is_available():
        pytest.skip("this machine has a CUDA GPU")
    result = _run_train(["--config", str(_config(tmp_path, tiny_dataset)), "--device", device])
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_training_on_a_gpu_runs_every_field_loss_through_the_refiner(tmp_path, tiny_dataset):
    config = _config(tmp_path, tiny_dataset, refiner_start=0, device="cuda", steps=2)
    result = _run_train(["--config", str(config)])
    assert result.returncode == 0, result.stderr
    lines = [json.loads(x) for x in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    steps = [x for x in lines if x["event"] == "train"]
    assert steps and all(np.isfinite(x["camera"]) and np.isfinite(x["total"]) for x in steps)


def test_the_teacher_never_holds_pairs_of_teacher_free_data(tmp_path, tiny_dataset):
    """Pure-rotation pairs with gravity are held to the teacher when they are ``data``, and never when they
    are ``teacher_free_data`` (views the fine-tune is to learn from their own truth); the checkpoint says
    which folders those were."""
    from stereogeo_cli.network.checkpoint import save_checkpoint

    crops = tmp_path / "crops"
    shutil.copytree(tiny_dataset, crops)
    records = [json.loads(line) for line in (crops / "calib.jsonl").read_text().splitlines()]
    (crops / "calib.jsonl").write_text(
        "".join(json.dumps({**r, "T": [0.0, 0.0, 0.0]}) + "\n" for r in records)
    )
    torch.manual_seed(6)
    init = save_checkpoint(tmp_path / "init.pt", StereoGeoNet({"pretrained": False}), training_data="unit")
    common = {
        "init": str(init), "teacher": str(init), "train_only": ["decoder", "up_head", "latitude_head"],
        "lr": 1e-2, "steps": 6, "batch_size": 4,
        "loss": {"teacher_weight": 4.0, "rotation_weight": 0.0, "translation_weight": 0.0},
    }  # fmt: skip

    def teacher_terms(out: str, data: Path, **settings) -> tuple[list[float], dict]:
        config = _config(tmp_path, data, **common, **settings, out=str(tmp_path / out))
        run = _run_train(["--config", str(config)])
        assert run.returncode == 0, run.stderr
        log = [json.loads(line) for line in (tmp_path / out / "log.jsonl").read_text().splitlines()]
        saved = torch.load(tmp_path / out / "latest.pt", weights_only=True)
        return [r["teacher"] for r in log if r["event"] == "train"], saved

    held, _ = teacher_terms("held", crops)
    assert max(held) > 0  # the student moves away from the teacher on the pairs it holds
    free, saved = teacher_terms("free", tiny_dataset, teacher_free_data=[str(crops)])
    assert free == [0.0] * len(free)
    assert f"{crops} (no teacher)" in saved["training_data"]
