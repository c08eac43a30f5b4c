"""Checkpoints of StereoGeoNet: one dict that ``torch.load(path, weights_only=True)`` reads.

Format: ``{"model": state_dict, "conf": model conf, "step": int, "stereogeo_version": str, ...}``; training
may add entries of plain types (optimizer state, RNG state, metrics, ``"training_data"``).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import torch

from stereogeo_cli import __version__
from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.network.model import StereoGeoNet


def give_default_permissions(path: str | os.PathLike) -> None:
    """mkstemp makes files 0600: give a finished temporary file the mode a new file would have."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(path, 0o666 & ~umask)


def save_checkpoint(path: str | os.PathLike, model: StereoGeoNet, step: int = 0, **extra: Any) -> Path:
    """Write a checkpoint atomically (temporary file, then rename) and return its path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    checkpoint = {
        "model": model.state_dict(),
        "conf": dict(model.conf),
        "step": int(step),
        "stereogeo_version": __version__,
        **extra,
    }
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
    try:
        return model_from_checkpoint(checkpoint), checkpoint
    except (RuntimeError, ValueError, KeyError, TypeError) as exc:
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise StereoGeoError(f"checkpoint {path} does not fit the model: {first_line}") from None


# Options added after models were shipped: their values for a checkpoint that predates them.
LEGACY_CONF: dict[str, Any] = {"pose_match_stride": 16, "pose_scale_votes": False}


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
