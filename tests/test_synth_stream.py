"""The streaming torch dataset: indices split over workers and ranks, and the tensors it yields."""

from __future__ import annotations

from unittest import mock

import numpy as np
import torch

from stereogeo_cli.synth.config import SynthConfig
from stereogeo_cli.synth.sample import sample_pair
from stereogeo_cli.synth.stream import SyntheticStereoStream

CONFIG = SynthConfig(texture_size=128, texture_layers=24, short_side=96, aspects=(4 / 3,), portrait_share=0.0)


def _indices(world: int, workers: int, length: int | None, epoch: int = 0) -> list[list[int]]:
    out = []
    for rank in range(world):
        for worker in range(workers):
            ds = SyntheticStereoStream(seed=0, config=CONFIG, length=length, rank=rank, world_size=world)
            ds.set_epoch(epoch)
            info = mock.Mock(id=worker, num_workers=workers)
            with mock.patch("stereogeo_cli.synth.stream.get_worker_info", return_value=info):
                it = ds.indices()
                out.append(list(it) if length is not None else [next(it) for _ in range(5)])
    return out


def test_every_index_rendered_once_over_ranks_and_workers():
    parts = _indices(world=2, workers=3, length=50)
    flat = sorted(i for part in parts for i in part)
    assert flat == list(range(50))
    parts = _indices(world=2, workers=3, length=50, epoch=2)
    assert sorted(i for part in parts for i in part) == list(range(100, 150))
    endless = _indices(world=2, workers=2, length=None)
    flat = [i for part in endless for i in part]
    assert len(set(flat)) == len(flat)


def test_yields_tensors_identical_to_the_api():
    ds = SyntheticStereoStream(seed=3, config=CONFIG, length=2)
    items = list(ds)
    assert [item["calib"]["index"] for item in items] == [0, 1]
    sample = sample_pair(3, 1, CONFIG)
    left = items[1]["left"]
    assert left.dtype == torch.float32 and left.shape == (3, sample.left.shape[0], sample.left.shape[1])
    assert np.array_equal((left * 255).round().byte().permute(1, 2, 0).numpy(), sample.left)
    np.testing.assert_allclose(
        items[1]["R"].numpy() @ items[1]["gravity_left"].numpy(),
        items[1]["gravity_right"].numpy(),
        atol=1e-12,
    )
