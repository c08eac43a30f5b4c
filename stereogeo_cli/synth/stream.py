"""A streaming torch dataset that renders pairs on the fly with the same sampler as make-data.

The only module of ``synth`` that imports torch. Each DataLoader worker (and each distributed rank)
renders its own share of indices with its own GL context, so nothing is rendered twice.
"""

from __future__ import annotations

import itertools
import os

import numpy as np
import torch
from torch.utils.data import IterableDataset, get_worker_info

from stereogeo_cli.synth.config import SynthConfig
from stereogeo_cli.synth.sample import StereoSample, sample_pair


def _distributed() -> tuple[int, int]:
    if torch.distributed.is_available() and torch.distributed.is_initialized():
        return torch.distributed.get_rank(), torch.distributed.get_world_size()
    return int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1))


def to_tensors(sample: StereoSample) -> dict:
    """A sample as tensors: left/right [3 x H x W] float32 in [0, 1], depth_left/right [H x W] metres
    (if rendered), K_left/K_right [3 x 3], R [3 x 3], T [3] metres, gravity_left/right [3] (float64),
    and the calib dict."""
    out = {
        "left": torch.from_numpy(np.ascontiguousarray(sample.left.transpose(2, 0, 1))).float() / 255.0,
        "right": torch.from_numpy(np.ascontiguousarray(sample.right.transpose(2, 0, 1))).float() / 255.0,
        "K_left": torch.tensor(sample.calib["left"]["K"], dtype=torch.float64),
        "K_right": torch.tensor(sample.calib["right"]["K"], dtype=torch.float64),
        "R": torch.tensor(sample.calib["R"], dtype=torch.float64),
        "T": torch.tensor(sample.calib["T"], dtype=torch.float64),
        "gravity_left": torch.tensor(sample.calib["left"]["gravity_up"], dtype=torch.float64),
        "gravity_right": torch.tensor(sample.calib["right"]["gravity_up"], dtype=torch.float64),
        "calib": sample.calib,
    }
    if sample.depth_left is not None:
        out["depth_left"] = torch.from_numpy(sample.depth_left)
        out["depth_right"] = torch.from_numpy(sample.depth_right)
    return out


class SyntheticStereoStream(IterableDataset):
    """Renders pairs ``start + k`` (k = 0, 1, … up to ``length``, or forever) of the dataset ``seed``.

    Indices are dealt round-robin over ``world_size × num_workers`` consumers (rank from
    torch.distributed when initialised, else the RANK / WORLD_SIZE environment variables, or the
    ``rank`` / ``world_size`` arguments), so every pair is rendered exactly once per pass.
    ``set_epoch(e)`` moves to fresh pairs: pass e renders indices ``start + e·length + k``.

    Yields dicts from :func:`to_tensors` (``as_tensors=True``) or :class:`StereoSample` objects.
    Images differ in size between pairs: batch them with a collate function that resizes/crops
    (or use batch_size=None).
    """

    def __init__(
        self,
        seed: int = 0,
        config: SynthConfig | None = None,
        length: int | None = None,
        start: int = 0,
        rank: int | None = None,
        world_size: int | None = None,
        as_tensors: bool = True,
    ):
        super().__init__()
        self.seed, self.config, self.length, self.start = seed, config or SynthConfig(), length, start
        self.rank, self.world_size, self.as_tensors = rank, world_size, as_tensors
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def indices(self) -> itertools.islice | range:
        """The indices this process / worker renders in the current epoch."""
        rank, world = _distributed()
        rank = self.rank if self.rank is not None else rank
        world = self.world_size if self.world_size is not None else world
        info = get_worker_info()
        worker, workers = (info.id, info.num_workers) if info is not None else (0, 1)
        consumer, consumers = rank * workers + worker, world * workers
        if self.length is None:
            return itertools.count(self.start + consumer, consumers)
        base = self.start + self.epoch * self.length
        return range(base + consumer, base + self.length, consumers)

    def __len__(self) -> int:
        if self.length is None:
            raise TypeError("an endless stream has no length")
        return self.length

    def __iter__(self):
        for index in self.indices():
            sample = sample_pair(self.seed, index, self.config)
            yield to_tensors(sample) if self.as_tensors else sample
