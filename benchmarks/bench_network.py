"""Speed of StereoGeoNet: torch forward per image, ONNX Runtime per view and per pair, training throughput.

    python benchmarks/bench_network.py --threads 2 --runs 20 --train-steps 6

Timings are medians over ``--runs`` calls after two warm-up calls. Sizes are (height x width) of the
network input: short side 320 with the long side cropped to a multiple of 32 (4:3 → 320 x 416,
16:9 → 320 x 544), plus 224 x 320 (the multiple-of-32 size nearest a 320 x 240 image).
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
import warnings
from pathlib import Path

import torch

from stereogeo_cli.network.export import export_onnx
from stereogeo_cli.network.model import StereoGeoNet

SIZES = ((224, 320), (320, 416), (320, 544))  # (height, width)


def median_ms(fn, runs: int) -> float:
    for _ in range(2):
        fn()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1000


class _OneView(torch.nn.Module):
    """The per-view part of the network (encoder, decoder, field heads), for timing one view alone."""

    def __init__(self, model: StereoGeoNet):
        super().__init__()
        self.model = model

    def forward(self, image: torch.Tensor):
        fields, _ = self.model.forward_view(image)
        return tuple(fields.values())


def onnx_session(path: Path, threads: int):
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def bench_inference(model: StereoGeoNet, threads: int, runs: int, workdir: Path) -> dict:
    pair_path = workdir / "pair.onnx"
    export_onnx(model, pair_path, parity_sizes=((224, 320), (320, 416)))
    view_path = workdir / "view.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            _OneView(model),
            (torch.rand(1, 3, 320, 416),),
            str(view_path),
            dynamo=False,
            external_data=False,
            opset_version=18,
            input_names=["image"],
            dynamic_axes={"image": {2: "height", 3: "width"}},
        )
    pair_session, view_session = onnx_session(pair_path, threads), onnx_session(view_path, threads)
    results = {}
    for h, w in SIZES:
        image = torch.rand(1, 3, h, w)
        array = image.numpy()
        with torch.no_grad():
            torch_ms = median_ms(lambda image=image: model.forward_view(image), runs)
        view_ms = median_ms(lambda a=array: view_session.run(None, {"image": a}), runs)
        pair_ms = median_ms(lambda a=array: pair_session.run(None, {"left": a, "right": a}), runs)
        results[f"{h}x{w}"] = {"torch_view_ms": torch_ms, "onnx_view_ms": view_ms, "onnx_pair_ms": pair_ms}
    return results


def bench_training(model: StereoGeoNet, steps: int, batch: int = 16, size=(192, 256)) -> dict:
    """Forward + backward + AdamW step with a stand-in loss on every output (the real losses are cheap)."""
    model.train()
    optimizer = torch.optim.AdamW(model.parameters(), lr=1e-4)
    left, right = torch.rand(batch, 3, *size), torch.rand(batch, 3, *size)

    def view_step():
        fields, _ = model.forward_view(left)
        loss = sum(v.mean() for v in fields.values())
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

    def pair_step():
        out = model(left, right)
        loss = sum(v.mean() for v in out.values())
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

    view_ms = median_ms(view_step, steps)
    pair_ms = median_ms(pair_step, steps)
    model.eval()
    return {
        "batch": batch,
        "size": f"{size[0]}x{size[1]}",
        "single_view_images_per_s": batch / (view_ms / 1000),
        "stereo_pairs_per_s": batch / (pair_ms / 1000),
        "stereo_images_per_s": 2 * batch / (pair_ms / 1000),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2, help="torch and ONNX Runtime intra-op threads")
    parser.add_argument("--runs", type=int, default=20, help="timed calls per inference measurement")
    parser.add_argument("--train-steps", type=int, default=6, help="timed training steps (batch 16)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args()

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    model = StereoGeoNet().eval()
    with tempfile.TemporaryDirectory() as tmp:
        inference = bench_inference(model, args.threads, args.runs, Path(tmp))
    training = bench_training(model, args.train_steps)
    results = {"threads": args.threads, "inference": inference, "training": training}
    if args.json:
        print(json.dumps(results, indent=2))
        return
    print(f"threads: {args.threads}, median of {args.runs} runs")
    print(f"{'input (h x w)':>14} {'torch/view':>11} {'onnx/view':>10} {'onnx/pair':>10}")
    for size, r in inference.items():
        print(f"{size:>14} {r['torch_view_ms']:9.1f}ms {r['onnx_view_ms']:8.1f}ms {r['onnx_pair_ms']:8.1f}ms")
    print(
        f"training, batch {training['batch']} at {training['size']}: "
        f"{training['single_view_images_per_s']:.1f} images/s (single view), "
        f"{training['stereo_pairs_per_s']:.1f} pairs/s "
        f"= {training['stereo_images_per_s']:.1f} images/s (stereo)"
    )


if __name__ == "__main__":
    main()
