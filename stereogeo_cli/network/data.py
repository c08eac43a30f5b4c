"""Training samples: stereo pairs (from a dataset folder or rendered on the fly) cut to a training size,
with the exact ground truth of the cut images.

Every sample is resized so that it covers the batch's training size, then centre-cropped to it: the focal
scales with the resize and the principal point stays at the centre, so the ground truth stays exact
while batches vary in aspect ratio and field of view.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import torch

from stereogeo_cli.geometry import ResizeCrop, apply_resize_crop
from stereogeo_cli.io.text import plural
from stereogeo_cli.network.runtime import DEPTH_STRIDE, cell_pixel_coordinates

TRAIN_SIZES = ((256, 192), (320, 192), (224, 224), (192, 256))  # (width, height): 4:3, 5:3, 1:1, 3:4
WIDE_SIZES = ((384, 192), (448, 192), (512, 192), (608, 192))  # 2:1, 2.33:1, 2.67:1, 3.17:1 (train wide_data)


def cover_crop(width: int, height: int, out_width: int, out_height: int) -> ResizeCrop:
    """Resize so the image covers (out_width, out_height), then centre-crop to exactly that size."""
    scale = max(out_width / width, out_height / height)
    rw, rh = max(out_width, round(width * scale)), max(out_height, round(height * scale))
    crop = ((rw - out_width) // 2, (rh - out_height) // 2)
    return ResizeCrop((width, height), scale, (rw, rh), crop, (out_width, out_height))


def _camera(calib_camera: dict, rc: ResizeCrop) -> tuple[float, np.ndarray]:
    K = np.asarray(calib_camera["K"], dtype=float)
    focal = rc.focal_to_output(0.5 * (K[0, 0] + K[1, 1]))
    g = calib_camera.get("gravity_up")
    return focal, np.full(3, np.nan) if g is None else np.asarray(g, dtype=float)


MATCH_STRIDE = 8  # the pose head's matching cells (``pose_match_stride``)
OCCLUSION_TOLERANCE = 0.03  # a left point is seen by the right camera if its depth there agrees this well


def _nearest(depth: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth [N] at the pixels nearest to ``points`` [N x 2] (input pixels) and whether they are inside."""
    h, w = depth.shape
    col, row = np.rint(points[:, 0]).astype(np.int64), np.rint(points[:, 1]).astype(np.int64)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    return depth[np.clip(row, 0, h - 1), np.clip(col, 0, w - 1)], inside


def match_targets(calib: dict, rc_left: ResizeCrop, rc_right: ResizeCrop, depth=None,
                  stride: int = MATCH_STRIDE) -> dict[str, np.ndarray]:  # fmt: skip
    """The true right position of every left stride-``stride`` cell of a cut pair, in the pose head's cell
    coordinates (pixels relative to the cut's centre over half its short side; the two cuts have one size).

    Returns ``infinity_xy`` [N x 2]: where a point at infinity seen by the cell's centre appears (the
    rotation alone; zeros without a pose); and with ``depth`` (left, right z-depth [H x W] of the uncut
    images, 0 = nothing hit: the sky) ``match_xy`` [N x 2] and ``match_valid`` [N]: where the cell's
    surface point appears, valid when it is in front of the right camera, inside its cut and not hidden
    (the right depth agrees within 3 %; a sky cell must see sky). Cells in row-major order, as the head's.
    """
    width, height = rc_left.out_size
    cells = np.stack(cell_pixel_coordinates(height // stride, width // stride, stride), -1).reshape(-1, 2)
    half = min(width, height) / 2
    offset = np.array([width / 2, height / 2])
    n = len(cells)
    out = {"infinity_xy": np.zeros((n, 2)), "match_xy": np.zeros((n, 2)), "match_valid": np.zeros(n, bool)}
    if calib.get("R") is None:
        return {k: v.astype(np.float32) if v.dtype != bool else v for k, v in out.items()}
    K1, K2 = np.asarray(calib["left"]["K"], float), np.asarray(calib["right"]["K"], float)
    R, T = np.asarray(calib["R"], float), np.asarray(calib["T"] or (0.0, 0.0, 0.0), float)
    rays = np.c_[rc_left.points_to_input(cells), np.ones(n)] @ np.linalg.inv(K1).T  # z = 1
    ahead = rays @ R.T
    z_inf = ahead[:, 2]
    seen = np.where(z_inf[:, None] > 1e-6, ahead[:, :2] / np.maximum(z_inf, 1e-6)[:, None], 0.0)
    at_infinity = rc_right.points_to_output(seen * np.diag(K2)[:2] + K2[:2, 2])
    out["infinity_xy"] = (at_infinity - offset) / half
    if depth is not None:
        depth_left, depth_right = depth
        d, _ = _nearest(depth_left, rc_left.points_to_input(cells))
        points = rays * d[:, None] @ R.T + T  # surface points in the right camera's frame
        sky = d <= 0
        z = np.where(sky, z_inf, points[:, 2])
        xy = np.where(sky[:, None], ahead[:, :2], points[:, :2]) / np.maximum(z, 1e-6)[:, None]
        right_px = xy * np.diag(K2)[:2] + K2[:2, 2]
        d_right, inside = _nearest(depth_right, right_px)
        target = rc_right.points_to_output(right_px)
        in_cut = np.all((target >= -0.5) & (target <= np.array([width, height]) - 0.5), axis=1)
        visible = np.where(sky, d_right <= 0, np.abs(d_right - z) <= OCCLUSION_TOLERANCE * z)
        out["match_xy"] = (target - offset) / half
        out["match_valid"] = (z > 1e-3) & inside & in_cut & visible
    return {k: v.astype(np.float32) if v.dtype != bool else v for k, v in out.items()}


DEPTH_MIN_COVER = 0.75  # a cell has a depth target when this share of its pixels hit something (not sky)


def depth_targets(depth: np.ndarray | None, rc: ResizeCrop, focal: float) -> np.ndarray:
    """The depth head's targets for one view cut by ``rc``: per stride-8 cell [H/8 x W/8] the median log
    z-depth of its pixels minus log(focal / half the short side), ``focal`` in pixels of the cut
    (:class:`stereogeo_cli.network.model.DepthHead`); NaN where the cell sees too much sky, or without a
    depth map (``depth``: z-depth of the uncut image, 0 for sky)."""
    width, height = rc.out_size
    out = np.full((height // DEPTH_STRIDE, width // DEPTH_STRIDE), np.nan, dtype=np.float32)
    if depth is None:
        return out
    resized = cv2.resize(np.asarray(depth, np.float32), rc.resized_size, interpolation=cv2.INTER_NEAREST)
    x, y = rc.crop
    cut = resized[y : y + out.shape[0] * DEPTH_STRIDE, x : x + out.shape[1] * DEPTH_STRIDE]
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.where(cut > 0, np.log(np.maximum(cut, 1e-6)), np.nan)
    blocks = logs.reshape(out.shape[0], DEPTH_STRIDE, out.shape[1], DEPTH_STRIDE).transpose(0, 2, 1, 3)
    blocks = blocks.reshape(*out.shape, -1)
    covered = np.isfinite(blocks).mean(-1) >= DEPTH_MIN_COVER
    if covered.any():
        out[covered] = np.nanmedian(blocks[covered], axis=-1) - np.log(focal / (min(width, height) / 2))
    return out


def training_sample(
    left: np.ndarray, right: np.ndarray, calib: dict, size: tuple[int, int], depth=None
) -> dict:
    """Cut a pair to ``size`` (width, height) and return tensors with its ground truth.

    Returns ``left``, ``right`` [3 x H x W] float32 in [0, 1]; ``focal`` [2] (left, right) in pixels of the
    cut images; ``gravity`` [2 x 3] up vectors (NaN when unknown); ``R`` [3 x 3], ``T`` [3] metres;
    ``has_pose`` and ``has_translation`` (bool tensors: a pure-rotation pair has T = 0); and the pose
    head's cells' :func:`match_targets` (``infinity_xy``, ``match_xy``, ``match_valid``; no match is valid
    without ``depth``, the uncut left and right depth maps); ``depth_left``, ``depth_right``: the depth
    head's :func:`depth_targets` (all NaN without ``depth``).
    """
    images, focals, gravities, cuts = [], [], [], []
    for image, cam in ((left, calib["left"]), (right, calib["right"])):
        h, w = image.shape[:2]
        rc = cover_crop(w, h, *size)
        cuts.append(rc)
        cut = apply_resize_crop(image, rc)
        images.append(torch.from_numpy(np.ascontiguousarray(cut.transpose(2, 0, 1))).float().div_(255.0))
        focal, g = _camera(cam, rc)
        focals.append(focal)
        gravities.append(g)
    has_pose = calib.get("R") is not None and calib.get("T") is not None
    R = np.asarray(calib["R"], dtype=float) if has_pose else np.eye(3)
    T = np.asarray(calib["T"], dtype=float) if has_pose else np.zeros(3)
    targets = match_targets(calib, cuts[0], cuts[1], depth)
    for v, view in enumerate(("left", "right")):
        targets[f"depth_{view}"] = depth_targets(None if depth is None else depth[v], cuts[v], focals[v])
    return {
        **{k: torch.from_numpy(v) for k, v in targets.items()},
        "left": images[0],
        "right": images[1],
        "focal": torch.tensor(focals, dtype=torch.float32),
        "gravity": torch.tensor(np.stack(gravities), dtype=torch.float32),
        "R": torch.tensor(R, dtype=torch.float32),
        "T": torch.tensor(T, dtype=torch.float32),
        "has_pose": torch.tensor(has_pose),
        "has_translation": torch.tensor(has_pose and float(np.linalg.norm(T)) > 1e-6),
    }


class FolderPairs:
    """Pairs of a dataset folder in the project's layout (left/, right/, calib.jsonl)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        calib_path = self.root / "calib.jsonl"
        if not calib_path.is_file():
            from stereogeo_cli.errors import StereoGeoError

            raise StereoGeoError(f"{self.root} is not a dataset folder: {calib_path} is missing")
        self.records = []
        for line in calib_path.read_text().splitlines():
            if line.strip():
                try:
                    self.records.append(json.loads(line))
                except json.JSONDecodeError:
                    continue  # a line cut by an interrupted writer

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, index: int) -> tuple[np.ndarray, np.ndarray, dict]:
        record = self.records[index]
        images = []
        for side in ("left", "right"):
            image = cv2.imread(str(self.root / side / f"{record['id']}.png"), cv2.IMREAD_COLOR)
            if image is None:
                raise FileNotFoundError(self.root / side / f"{record['id']}.png")
            images.append(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
        return images[0], images[1], record

    def depth(self, index: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The pair's left and right depth maps (``make-data --depth``), or None if it has none."""
        paths = [
            self.root / "depth" / side / f"{self.records[index]['id']}.npy" for side in ("left", "right")
        ]
        if not all(p.is_file() for p in paths):
            return None
        return np.load(paths[0]), np.load(paths[1])


class RenderedPairs:
    """Pairs rendered on the fly by the synthetic sampler: pair i of dataset ``seed`` is always the same."""

    def __init__(self, seed: int, count: int, config=None):
        self.seed, self.count, self.config = seed, count, config

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, index: int) -> tuple[np.ndarray, np.ndarray, dict]:
        from stereogeo_cli.synth.sample import sample_pair

        sample = sample_pair(self.seed, index, self.config)
        return sample.left, sample.right, sample.calib


def change_sharpness(image: torch.Tensor, sigma: float, amount: float) -> torch.Tensor:
    """A [3 x H x W] image in [0, 1] blurred (``amount`` < 0 ... -1: a blend towards a Gaussian blur of
    ``sigma`` px) or sharpened (``amount`` > 0: an unsharp mask of that strength)."""
    hwc = np.ascontiguousarray(image.permute(1, 2, 0).numpy())
    blurred = cv2.GaussianBlur(hwc, (0, 0), sigma)
    out = hwc + (blurred - hwc) * -amount if amount < 0 else hwc + (hwc - blurred) * amount
    return torch.from_numpy(np.clip(out, 0.0, 1.0).transpose(2, 0, 1).copy())


def to_grey(image: np.ndarray) -> np.ndarray:
    """An RGB image [H x W x 3] uint8 as a mono camera gives it: luma in all three channels."""
    return cv2.cvtColor(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), cv2.COLOR_GRAY2RGB)


class TrainingPairs(torch.utils.data.Dataset):
    """Map-style dataset over several sources; items are addressed as (global index, size index, epoch).

    With ``grey_share`` > 0 that share of the pairs is shown in grey, both views alike (many stereo rigs
    are mono). With ``sharpness_share`` > 0 that share is blurred or sharpened after the cut, both views
    alike, half each way (blur of 0.5–2 px, unsharp mask of strength 0.3–1.5), so that how sharp an image
    looks stops telling its field of view (docs/network.md, "Sharpness and narrow real photographs").
    Which pairs is drawn from (``seed``, epoch, index), so it is reproducible and changes with the epoch.
    ``teacher_free`` (one bool per source) marks the sources whose pairs the teacher never holds (sample
    key ``teacher_free``).
    """

    def __init__(self, sources: list, sizes=TRAIN_SIZES, grey_share: float = 0.0, seed: int = 0,
                 sharpness_share: float = 0.0, teacher_free: list[bool] | None = None):  # fmt: skip
        self.sources = sources
        self.sizes = tuple(tuple(s) for s in sizes)
        self.offsets = np.cumsum([0] + [len(s) for s in sources])
        self.grey_share, self.seed = float(grey_share), int(seed)
        self.sharpness_share = float(sharpness_share)
        self.teacher_free = list(teacher_free) if teacher_free is not None else [False] * len(sources)
        if len(self.teacher_free) != len(sources):
            raise ValueError("teacher_free needs one flag per source")

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def __getitem__(self, item: tuple[int, int, int]) -> dict:
        index, size_index, epoch = item
        source = int(np.searchsorted(self.offsets, index, side="right") - 1)
        local = index - int(self.offsets[source])
        left, right, calib = self.sources[source][local]
        depth = self.sources[source].depth(local) if hasattr(self.sources[source], "depth") else None
        if (
            self.grey_share > 0
            and np.random.default_rng([self.seed, epoch, index]).random() < self.grey_share
        ):
            left, right = to_grey(left), to_grey(right)
        sample = training_sample(left, right, calib, self.sizes[size_index], depth)
        if self.sharpness_share > 0:
            rng = np.random.default_rng([self.seed, epoch, index, 1])  # apart from the grey draw
            if rng.random() < self.sharpness_share:
                if rng.random() < 0.5:
                    sigma, amount = rng.uniform(0.5, 2.0), -rng.uniform(0.5, 1.0)
                else:
                    sigma, amount = 1.0, rng.uniform(0.3, 1.5)
                for view in ("left", "right"):
                    sample[view] = change_sharpness(sample[view], sigma, amount)
        sample["teacher_free"] = torch.tensor(bool(self.teacher_free[source]))
        sample["index"] = torch.tensor(index)
        sample["size_index"] = torch.tensor(size_index)
        return sample


class SizedBatches(torch.utils.data.Sampler):
    """Batches of one training size each, shuffled per epoch from a seed; split across ranks.

    Items are (index, size index, epoch). ``n_sizes`` is the number of ordinary sizes.

    ``wide`` = (first wide index, number of wide sizes, share): the indices from the first wide one on
    form a pool of their own, drawn only into wide batches, whose size indices follow the ordinary ones;
    wide batches are ``share`` of all (the wide pool is cycled if it is smaller than that needs). Without
    ``wide`` the draws are one permutation of all pairs, then one size per batch, in that order: the stream
    a seed gives does not depend on the wide-batch code.

    Iteration starts at ``start_batch`` of the stream of epochs, so a resumed run sees exactly the
    batches it would have seen without the interruption.
    """

    def __init__(self, count: int, batch_size: int, n_sizes: int, seed: int, rank: int = 0, world: int = 1,
                 start_batch: int = 0, wide: tuple[int, int, float] | None = None):  # fmt: skip
        self.count, self.batch_size, self.n_sizes = count, batch_size, n_sizes
        self.seed, self.rank, self.world, self.start_batch = seed, rank, world, start_batch
        self.wide = wide
        ordinary = count if wide is None else wide[0]
        self.n_ordinary = ordinary // (batch_size * world) * world  # batches per epoch, all ranks
        self.n_wide = 0
        if wide is not None:
            if not 0.0 <= wide[2] < 1.0 or count - ordinary < 1:
                raise ValueError("wide batches need a share in [0, 1) and at least one wide pair")
            self.n_wide = round(self.n_ordinary * wide[2] / (1.0 - wide[2]) / world) * world
        self.per_epoch = (self.n_ordinary + self.n_wide) // world
        if self.n_ordinary < 1:
            processes = plural(world, "process", "processes")
            few = f"{plural(ordinary, 'pair')} {'is' if ordinary == 1 else 'are'} too few"
            raise ValueError(f"{few} for batches of {batch_size} on {processes}")

    def epoch_batches(self, epoch: int) -> list[list[tuple[int, int, int]]]:
        rng = np.random.default_rng([self.seed, epoch])
        if self.wide is None:
            order = rng.permutation(self.count)[: self.per_epoch * self.batch_size * self.world]
            sizes = rng.integers(self.n_sizes, size=self.per_epoch * self.world)
            batches = order.reshape(-1, self.batch_size)
        else:
            first, n_wide_sizes, _ = self.wide
            ordinary = rng.permutation(first)[: self.n_ordinary * self.batch_size]
            need, pool = self.n_wide * self.batch_size, self.count - first
            cycles = [rng.permutation(pool) for _ in range(-(-need // pool))] if need else []
            wide = first + np.concatenate(cycles or [np.zeros(0, dtype=int)])[:need]
            batches = np.concatenate([ordinary, wide]).reshape(-1, self.batch_size)
            sizes = np.concatenate([
                rng.integers(self.n_sizes, size=self.n_ordinary),
                self.n_sizes + rng.integers(n_wide_sizes, size=self.n_wide),
            ])  # fmt: skip
            shuffle = rng.permutation(len(batches))
            batches, sizes = batches[shuffle], sizes[shuffle]
        mine = range(self.rank, len(batches), self.world)
        return [[(int(i), int(sizes[b]), epoch) for i in batches[b]] for b in mine]

    def __iter__(self):
        epoch, skip = divmod(self.start_batch, self.per_epoch)
        while True:
            yield from self.epoch_batches(epoch)[skip:]
            epoch, skip = epoch + 1, 0

    def __len__(self) -> int:  # an endless stream; DataLoader only needs a number
        return 1 << 40
