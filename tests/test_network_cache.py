"""The optimised-graph cache of the ONNX session: a later process reads the graph ONNX Runtime optimised
before, and its outputs are the same bit for bit; a damaged file or an unwritable folder only costs time."""

import numpy as np
import pytest

from stereogeo_cli.network.runtime import CACHE_ENV, FieldNetwork, cache_folder


@pytest.fixture
def pair():
    rng = np.random.default_rng(3)
    return rng.integers(0, 256, (240, 320, 3), dtype=np.uint8), rng.integers(
        0, 256, (240, 300, 3), dtype=np.uint8
    )


def _outputs(network: FieldNetwork, pair) -> list[np.ndarray]:
    out = network.predict(*pair)
    views = [
        getattr(view, name) for view in (out.left, out.right) for name in ("up", "latitude", "up_confidence")
    ]
    return [*views, out.quaternion, out.translation]


def test_the_cached_graph_gives_the_outputs_of_the_optimised_model_bit_for_bit(
    onnx_model, tmp_path, monkeypatch, pair
):
    monkeypatch.setenv(CACHE_ENV, "")
    plain = FieldNetwork(onnx_model, threads=1)
    assert plain.graph_file == onnx_model and cache_folder() is None

    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "cache"))
    first = FieldNetwork(onnx_model, threads=1)  # optimises the model and keeps the result
    cached = sorted((tmp_path / "cache").iterdir())
    assert first.graph_file == onnx_model and [p.suffix for p in cached] == [".onnx"]  # no partial file left
    second = FieldNetwork(onnx_model, threads=1)
    assert second.graph_file == cached[0]
    assert second.metadata == plain.metadata
    for a, b, c in zip(_outputs(plain, pair), _outputs(first, pair), _outputs(second, pair), strict=True):
        assert np.array_equal(a, b) and np.array_equal(a, c)


def test_a_damaged_cache_file_is_optimised_again_and_replaced(onnx_model, tmp_path, monkeypatch, pair):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    reference = _outputs(FieldNetwork(onnx_model, threads=1), pair)
    (graph,) = tmp_path.glob("*.onnx")
    graph.write_bytes(graph.read_bytes()[: graph.stat().st_size // 3])  # a write cut short
    network = FieldNetwork(onnx_model, threads=1)
    assert network.graph_file == onnx_model
    assert all(np.array_equal(a, b) for a, b in zip(reference, _outputs(network, pair), strict=True))
    assert FieldNetwork(onnx_model, threads=1).graph_file == graph  # whole again


def test_a_cache_folder_that_cannot_be_made_leaves_the_network_working(onnx_model, tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv(CACHE_ENV, str(blocker / "cache"))
    network = FieldNetwork(onnx_model, threads=1)
    assert network.graph_file == onnx_model and blocker.read_text() == "not a folder"
    assert network.metadata["input_short_side"]
