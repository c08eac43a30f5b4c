"""Checkpoints of StereoGeoNet: one dict that ``torch.load(path, weights_only=True)`` reads.

Format: ``{"model": state_dict, "conf": model conf, "step": int, "stereogeo_version": str, ...}``; training
may add entries of plain types (optimizer state, RNG state, metrics, ``"training_data"``).
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path
from typing import Any

import torch

from stereogeo_cli import __version__
from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.network.model import StereoGeoNet
from stereogeo_cli.network.runtime import file_sha256


def give_default_permissions(path: str | os.PathLike) -> None:
    """mkstemp makes files 0600: give a finished temporary file the mode a new file would have."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)


def save_checkpoint(path: str | os.PathLike, model: StereoGeoNet, step: int = 0, **extra: Any) -> Path:
    """Write a checkpoint of ``model`` atomically (temporary file, then rename) and return its path."""
    checkpoint = {
        "model": model.state_dict(),
        "conf": dict(model.conf),
        "step": int(step),
        "stereogeo_version": __version__,
        **extra,
    }
    return write_checkpoint(path, checkpoint)


def write_checkpoint(path: str | os.PathLike, checkpoint: dict[str, Any]) -> Path:
    """Write a checkpoint dict atomically (temporary file, then rename): a file already at ``path`` stays
    whole until the new one is complete. Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save(checkpoint, f)
        give_default_permissions(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _read(path: str | os.PathLike) -> Any:
    """``torch.load(path, weights_only=True)`` on the CPU; a missing or unreadable file: StereoGeoError."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise StereoGeoError(f"checkpoint not found: {path}") from None
    except Exception as exc:  # torch raises many types for files that are not checkpoints
        raise StereoGeoError(f"cannot read checkpoint {path}: {type(exc).__name__}") from None


def load_checkpoint(path: str | os.PathLike) -> tuple[StereoGeoNet, dict[str, Any]]:
    """Read a checkpoint → (model in eval mode, checkpoint dict); bad files raise StereoGeoError."""
    checkpoint = _read(path)
    if not isinstance(checkpoint, dict) or "model" not in checkpoint or "conf" not in checkpoint:
        raise StereoGeoError(f"{path} is not a stereogeo checkpoint (no 'model' and 'conf' entries)")
    return _built(checkpoint, f"checkpoint {path}"), checkpoint


def _built(checkpoint: dict[str, Any], what: str) -> StereoGeoNet:
    """:func:`model_from_checkpoint`, its failures as a one-line StereoGeoError naming ``what``."""
    try:
        return model_from_checkpoint(checkpoint)
    except (RuntimeError, ValueError, KeyError, TypeError) as exc:
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise StereoGeoError(f"{what} does not fit the model: {first_line}") from None


# A checkpoint whose conf lacks these options holds a model built without them: these values rebuild it.
LEGACY_CONF: dict[str, Any] = {"pose_match_stride": 16, "pose_scale_votes": False}


def _architecture(checkpoint: dict) -> dict[str, Any]:
    """The model a checkpoint holds: its conf with the defaults it leaves out, less ``pretrained`` (which
    decides only the encoder's first weights: a fine-tune started from a checkpoint has it off)."""
    conf = {**StereoGeoNet.default_conf, **LEGACY_CONF, **checkpoint.get("conf", {})}
    conf.pop("pretrained", None)
    return conf


def model_from_checkpoint(checkpoint: dict[str, Any]) -> StereoGeoNet:
    """Build the model of a checkpoint dict and load its weights (strict), in eval mode."""
    model = StereoGeoNet({**LEGACY_CONF, **checkpoint["conf"], "pretrained": False})
    model.load_state_dict(checkpoint["model"], strict=True)
    return model.eval()


def init_from_checkpoint(model: StereoGeoNet, path: str | os.PathLike) -> list[str]:
    """Copy into ``model`` every tensor of the checkpoint at ``path`` whose name and shape match (fine-tuning
    across a change of architecture, e.g. a new pose head). Returns the names of the model's parameters and
    buffers left as they were, sorted; a checkpoint that shares nothing with the model raises."""
    checkpoint = _read(path)
    if not isinstance(checkpoint, dict) or not isinstance(checkpoint.get("model"), dict):
        raise StereoGeoError(f"{path} is not a stereogeo checkpoint (no 'model' entry)")
    own = model.state_dict()
    taken = {
        name: tensor
        for name, tensor in checkpoint["model"].items()
        if name in own and tuple(own[name].shape) == tuple(tensor.shape)
    }
    if not taken:
        raise StereoGeoError(f"checkpoint {path} shares no weights with the model")
    model.load_state_dict(taken, strict=False)
    return sorted(set(own) - set(taken))


# Entries of a training checkpoint that belong to its run, not to its weights: an average leaves them out.
_RUN_STATE = ("optimizer", "rng", "best", "teacher_sha256")


def average_checkpoints(paths: list[str | os.PathLike], weights: list[float]) -> dict[str, Any]:
    """The weighted average of the weights of several checkpoints of one architecture (a "model soup";
    with a model and its own fine-tune, WiSE-FT): a checkpoint dict that :func:`load_checkpoint` and
    ``export-onnx`` read.

    Fine-tunes that started from the same weights lie in one basin of the loss, where their average is a
    model of its own, often better than either (Wortsman et al. 2022). Floating-point tensors are averaged
    (in float64, stored in their own dtype); integer buffers (batch-norm step counts) are the first
    checkpoint's. The other entries are the first checkpoint's, without its run state (optimizer, RNG),
    with ``averaged_from`` (each input's path, version, SHA-256 and weight) and the lineage extended.

    Args:
        paths: two or more checkpoints.
        weights: one positive weight per checkpoint; they are scaled to sum to 1.
    Raises:
        StereoGeoError: unreadable files, weights that do not fit, or checkpoints of different models.
    """
    if len(paths) < 2:
        raise StereoGeoError("averaging needs at least two checkpoints")
    if len(weights) != len(paths):
        raise StereoGeoError(f"{len(paths)} checkpoints need {len(paths)} weights, got {len(weights)}")
    if not all(math.isfinite(w) and w > 0 for w in weights):
        raise StereoGeoError(f"the weights must be positive numbers, got {', '.join(map(str, weights))}")
    total = float(sum(weights))
    shares = [float(w) / total for w in weights]
    checkpoints = []
    for path in paths:
        checkpoint = _read(path)
        if not isinstance(checkpoint, dict) or not isinstance(checkpoint.get("model"), dict):
            raise StereoGeoError(f"{path} is not a stereogeo checkpoint (no 'model' entry)")
        checkpoints.append(checkpoint)
    first = checkpoints[0]
    for path, checkpoint in zip(paths[1:], checkpoints[1:], strict=True):
        if _architecture(checkpoint) != _architecture(first):
            raise StereoGeoError(f"{path} is a different model from {paths[0]} (their 'conf' entries differ)")
        own, other = first["model"], checkpoint["model"]
        if set(own) != set(other) or any(tuple(own[k].shape) != tuple(other[k].shape) for k in own):
            raise StereoGeoError(f"{path} does not hold the same tensors as {paths[0]}")
    averaged = {}
    for name, tensor in first["model"].items():
        if tensor.is_floating_point():
            mean = sum(
                share * c["model"][name].double() for share, c in zip(shares, checkpoints, strict=True)
            )
            averaged[name] = mean.to(tensor.dtype)
        else:
            averaged[name] = tensor.clone()
    sources = [
        {
            "path": str(path),
            "model_version": str(c.get("model_version", "unnamed")),
            "sha256": file_sha256(path),
            "weight": share,
        }
        for path, c, share in zip(paths, checkpoints, shares, strict=True)
    ]
    summary = " + ".join(f"{s['weight']:.3g} × {s['model_version']}" for s in sources)
    result = {k: v for k, v in first.items() if k not in _RUN_STATE}
    result.update(
        model=averaged,
        stereogeo_version=__version__,
        averaged_from=sources,
        lineage=f"{first['lineage']} -> weight average {summary}" if first.get("lineage") else summary,
    )
    _built(result, f"the average of {paths[0]} and the others")  # the check load_checkpoint makes
    return result
