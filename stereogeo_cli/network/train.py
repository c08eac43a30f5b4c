"""Training of StereoGeoNet on stereo pairs with exact ground truth (resumable, optionally distributed).

Run with ``stereogeo train`` or, for several processes, ``torchrun --nproc_per_node 2 -m
stereogeo_cli.network.train ...`` (gloo backend). Every ``checkpoint_minutes`` the state is written to
``OUT/latest.pt`` (atomically); ``--resume`` continues from it with the same batches it would have seen.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.distributed as dist

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.network.checkpoint import init_from_checkpoint, load_checkpoint, save_checkpoint
from stereogeo_cli.network.data import (
    TRAIN_SIZES,
    WIDE_SIZES,
    FolderPairs,
    RenderedPairs,
    SizedBatches,
    TrainingPairs,
)
from stereogeo_cli.network.losses import compute_losses
from stereogeo_cli.network.losses import default_conf as loss_defaults
from stereogeo_cli.network.model import OUTPUT_STRIDE, StereoGeoNet
from stereogeo_cli.network.runtime import file_sha256
from stereogeo_cli.settings import resolve

SETTINGS: dict[str, tuple[Any, str]] = {  # name: (default, what it does)
    "data": ([], "Dataset folders (left/, right/, calib.jsonl) to train on."),
    "render": (0, "Additionally render this many pairs on the fly (synthetic sampler), 0 for none."),
    "render_seed": (1000, "Dataset seed of the on-the-fly pairs."),
    "panoramas": (None, "Panorama folder for the on-the-fly pairs' skies and crops."),
    "render_config": (
        {},
        "Sampler settings of the on-the-fly pairs over make-data's defaults (SynthConfig fields, e.g. "
        '{"vfov_deg": [18, 75], "aspects": [2.0, 2.4], "panorama_max_upsampling": 3.5}).',
    ),
    "val": (None, "Dataset folder for validation (rendered from seeds never used in training)."),
    "val_count": (64, "Validation pairs used."),
    "out": ("runs/train", "Where checkpoints and logs go."),
    "steps": (6000, "Optimiser steps in all."),
    "batch_size": (8, "Pairs per step and process."),
    "sizes": ([list(s) for s in TRAIN_SIZES], "Training sizes (width, height); one per batch."),
    "teacher_free_data": (
        [],
        "Dataset folders trained on like data, whose pairs the teacher never holds (teacher_weight): views "
        "the teacher reads wrong and the fine-tune is to learn from their own truth, e.g. sharp narrow "
        "crops of high-resolution panoramas.",
    ),
    "wide_data": (
        [],
        "Dataset folders of wide frames (make-data --aspects 2:1,12:5,33:10): they fill wide_share of the "
        "batches, cut to wide_sizes, and no other batch draws from them.",
    ),
    "wide_sizes": (
        [list(s) for s in WIDE_SIZES],
        "Training sizes (width, height) of the wide batches; one per batch.",
    ),
    "wide_share": (0.3, "Share of the batches that are wide (when wide_data is given)."),
    "grey_share": (
        0.0,
        "Share of training pairs shown in grey, both views alike (as mono cameras give them).",
    ),
    "sharpness_share": (
        0.0,
        "Share of training pairs blurred or sharpened after the cut, both views alike, so sharpness does "
        "not tell the field of view.",
    ),
    "input_short_side": (224, "The inference rule written into the exported model (short side, pixels)."),
    "lr": (1e-4, "AdamW learning rate after warm-up."),
    "weight_decay": (1e-4, "AdamW weight decay."),
    "warmup_steps": (300, "Linear warm-up from 0."),
    "decay_at": ([0.7, 0.9], "Fractions of ``steps`` where the learning rate is multiplied by 0.1."),
    "clip_grad": (1.0, "Gradient-norm clipping."),
    "refiner_start": (500, "The camera loss through the unrolled refiner starts after this many steps."),
    "loss": ({}, "Overrides of stereogeo_cli.network.losses.default_conf."),
    "val_every": (500, "Validation every this many steps (and at the end)."),
    "checkpoint_minutes": (5.0, "Write OUT/latest.pt at least this often."),
    "log_every": (20, "A progress line every this many steps."),
    "threads": (2, "Torch intra-op threads per process."),
    "device": ("cpu", "Torch device of the model and the losses (cpu, cuda); data loading stays on the CPU."),
    "workers": (1, "Data-loading processes per training process."),
    "seed": (0, "Model init, batch order."),
    "model_version": (None, "A name for the model (default: OUT's folder name)."),
    "model": ({}, "StereoGeoNet options (e.g. pose_match_stride), over the model's defaults."),
    "train_only": (
        [],
        "Train only the modules with these name prefixes (e.g. pose_head); the rest is frozen, batch norm "
        "statistics included, so a new head can be trained without changing the fields.",
    ),
    "teacher": (
        None,
        "A checkpoint held frozen as a teacher: with loss teacher_weight > 0 the student's fields are held "
        "to its fields on the crops of real panoramas (pure-rotation pairs), so a fine-tune on renders "
        "keeps the teacher's reading of real photographs (distillation, 'learning without forgetting').",
    ),
    "init": (
        None,
        "Start from the weights of this checkpoint (e.g. models/stereogeo.pt) instead of ImageNet; every "
        "weight whose name and shape match is taken, the rest (a changed head) starts fresh and is logged.",
    ),
}
default_conf: dict[str, Any] = {key: value for key, (value, _) in SETTINGS.items()}


def lr_at(step: int, conf: dict) -> float:
    """Linear warm-up, then a step decay ×0.1 at each fraction of ``decay_at``."""
    if step < conf["warmup_steps"]:
        return conf["lr"] * (step + 1) / conf["warmup_steps"]
    passed = sum(step >= frac * conf["steps"] for frac in conf["decay_at"])
    return conf["lr"] * 0.1**passed


def _device(name: str) -> torch.device:
    """The torch device named by the ``device`` setting; an unknown or absent one is a clear error."""
    try:
        device = torch.device(name)
    except RuntimeError as error:
        raise StereoGeoError(f"device {name!r} is not a torch device (cpu, cuda, cuda:1, ...)") from error
    if device.type == "cuda" and not torch.cuda.is_available():
        raise StereoGeoError(f"device {name!r}: this machine's torch sees no CUDA GPU")
    return device


def _distributed() -> tuple[int, int]:
    if "RANK" in os.environ and "WORLD_SIZE" in os.environ and int(os.environ["WORLD_SIZE"]) > 1:
        if not dist.is_initialized():
            dist.init_process_group("gloo")
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def _sync_buffers(model: torch.nn.Module, world: int) -> None:
    """Average the batch-norm statistics over the processes (each saw its own batches), so that every
    replica holds the same model; counters are taken from rank 0."""
    if world < 2:
        return
    for buffer in model.buffers():
        if buffer.is_floating_point():
            dist.all_reduce(buffer, op=dist.ReduceOp.SUM)
            buffer.div_(world)
        else:
            dist.broadcast(buffer, 0)


def _agree(flag: bool, world: int) -> bool:
    """Rank 0's decision, for every rank (a decision that leads to a collective must be shared)."""
    if world < 2:
        return flag
    value = torch.tensor([int(flag)])
    dist.broadcast(value, 0)
    return bool(value.item())


def _to_float(losses: dict) -> dict[str, float]:
    return {k: float(v.detach()) for k, v in losses.items()}


def _sources(conf: dict) -> list:
    sources: list = [FolderPairs(d) for d in conf["data"] + conf["teacher_free_data"]]
    if conf["render"]:
        from stereogeo_cli.synth.config import SynthConfig

        panoramas = Path(conf["panoramas"]) if conf["panoramas"] else None
        fields = set(SynthConfig.__dataclass_fields__)
        unknown = set(conf["render_config"]) - fields
        if unknown:
            raise StereoGeoError(f"unknown render_config settings: {sorted(unknown)}")
        changes = {k: tuple(v) if isinstance(v, list) else v for k, v in conf["render_config"].items()}
        config = SynthConfig(panoramas=panoramas).replace(**changes)
        sources.append(RenderedPairs(conf["render_seed"], conf["render"], config))
    if not sources:
        raise StereoGeoError("no training data: give --data FOLDER (from make-data) or --render N")
    return sources


@torch.no_grad()
def validate(
    model: StereoGeoNet, val: FolderPairs, count: int, short_side: int, flip: bool = False
) -> dict[str, float]:
    """The product's path on validation pairs: resize/crop, network, NumPy refiner; errors in degrees.

    ``flip``: average the fields with the mirrored pair's (``calibrate``'s ``flip`` option, off by default).
    Returns medians and AUC@1/5/10 (held flat below 1°) of roll, pitch and vFoV errors (both cameras), and
    the median and 68th percentile of the pose head's errors: rotation and translation direction (degrees),
    translation ``|T̂ - T| / |T|`` and length ``| |T̂| / |T| - 1 |`` (shares of the baseline).
    """
    was_training = model.training
    device = next(model.parameters()).device
    model.eval()
    errors: dict[str, list[float]] = {
        k: [] for k in ("roll", "pitch", "vfov", "rotation", "translation", "direction", "scale")
    }
    for i in range(min(count, len(val))):
        left, right, calib = val[i]
        out, rcs = _validation_outputs(model, left, right, short_side, flip, device)
        _camera_errors(out, calib, rcs, errors)
        _pose_errors(out, calib, errors)
    model.train(was_training)
    return _validation_metrics(errors)


def _validation_outputs(
    model: StereoGeoNet, left: np.ndarray, right: np.ndarray, short_side: int, flip: bool, device
) -> tuple[dict[str, np.ndarray], list]:
    """The network's outputs (first batch item, float64) on a pair cut as the product cuts it, and each
    view's resize/crop."""
    from stereogeo_cli.geometry import apply_resize_crop, resize_crop_for_network
    from stereogeo_cli.network.runtime import average_with_mirrored

    tensors, rcs = [], []
    for image in (left, right):
        rc = resize_crop_for_network(image.shape[1], image.shape[0], short_side)
        cut = apply_resize_crop(image, rc)
        tensors.append(torch.from_numpy(np.ascontiguousarray(cut.transpose(2, 0, 1)))[None].float() / 255)
        rcs.append(rc)
    tensors = [t.to(device) for t in tensors]
    raw = {k: v.cpu().numpy() for k, v in model(*tensors).items()}
    if flip:  # as calibrate's flip option: fields averaged with the mirrored pair's (pose: the plain run's)
        mirrored = {k: v.cpu().numpy() for k, v in model(*(t.flip(-1) for t in tensors)).items()}
        raw = average_with_mirrored(raw, mirrored)
    return {k: v[0].astype(float) for k, v in raw.items()}, rcs


def _camera_errors(
    out: dict[str, np.ndarray], calib: dict, rcs: list, errors: dict[str, list[float]]
) -> None:
    """Append the roll, pitch and vFoV errors (degrees) of the refined cameras of the views with gravity."""
    from stereogeo_cli.geometry import roll_pitch_from_gravity, vfov_from_focal
    from stereogeo_cli.network.runtime import cell_pixel_coordinates
    from stereogeo_cli.refine import refine_camera

    for view, rc in zip(("left", "right"), rcs, strict=True):
        cam = calib[view]
        if cam.get("gravity_up") is None:
            continue
        h, w = out[f"{view}_latitude"].shape
        fit = refine_camera(
            out[f"{view}_up"].transpose(1, 2, 0), out[f"{view}_latitude"],
            out[f"{view}_up_confidence"], out[f"{view}_latitude_confidence"],
            image_size=rc.out_size, pixel_xy=cell_pixel_coordinates(h, w, OUTPUT_STRIDE),
        )  # fmt: skip
        fit = fit.in_original_pixels(rc)
        roll, pitch = np.degrees(roll_pitch_from_gravity(np.asarray(cam["gravity_up"])))
        K = np.asarray(cam["K"])
        vfov = np.degrees(vfov_from_focal(K[1, 1], cam["height"]))
        errors["roll"].append(abs((fit.roll_deg - roll + 180) % 360 - 180))
        errors["pitch"].append(abs(fit.pitch_deg - pitch))
        errors["vfov"].append(abs(fit.vfov_deg - vfov))


def _pose_errors(out: dict[str, np.ndarray], calib: dict, errors: dict[str, list[float]]) -> None:
    """Append the pose head's rotation error and, for a rig with a baseline, its translation errors."""
    from stereogeo_cli.geometry import gravity_angle, rotation_error
    from stereogeo_cli.geometry import quaternion_to_rotation as quat_np

    if calib.get("R") is None:
        return
    errors["rotation"].append(np.degrees(rotation_error(quat_np(out["quaternion"]), np.asarray(calib["R"]))))
    T = np.asarray(calib["T"], dtype=float)
    t_hat, length = out["translation"], float(np.linalg.norm(T))
    if length > 1e-6:
        errors["translation"].append(float(np.linalg.norm(t_hat - T) / length))
        errors["direction"].append(float(np.degrees(gravity_angle(t_hat, T))))
        errors["scale"].append(abs(float(np.linalg.norm(t_hat)) / length - 1.0))


def _validation_metrics(errors: dict[str, list[float]]) -> dict[str, float]:
    """The summary of the collected errors that :func:`validate` returns."""
    from stereogeo_cli.metrics import summarize

    metrics: dict[str, float] = {}
    for name in ("roll", "pitch", "vfov"):
        for key, value in summarize(np.array(errors[name]), min_error=1.0).items():
            metrics[f"{name}_{key}"] = value
    # The pose head alone: medians, and the 68th percentiles that serve as its 1-sigma in the product
    # (export-onnx --pose-sigmas) and in the fusion's priors.
    for name, unit in (("rotation", "deg"), ("direction", "deg"), ("translation", "rel"), ("scale", "rel")):
        values = np.array(errors[name])
        metrics[f"{name}_median_{unit}"] = float(np.median(values)) if values.size else math.nan
        metrics[f"{name}_p68_{unit}"] = float(np.percentile(values, 68.27)) if values.size else math.nan
    return metrics


def set_training(model: torch.nn.Module, prefixes: tuple[str, ...]) -> None:
    """Training mode for the trained modules; frozen ones (not under ``prefixes``) stay in eval mode, so
    their batch-norm statistics do not move."""
    model.train()
    if prefixes:
        for name, module in model.named_modules():
            if name and not name.startswith(prefixes) and not any(p.startswith(name + ".") for p in prefixes):
                module.eval()


class _Log:
    """Progress lines on stderr and one JSON object per event in OUT/log.jsonl (rank 0 only)."""

    def __init__(self, out: Path, active: bool):
        self.active = active
        self.path = out / "log.jsonl"
        self.silent: set[str] = set()  # events written to the log file only (a progress bar shows them)

    def __call__(self, event: str, **values) -> None:
        if not self.active:
            return
        record = {"event": event, "time": time.time(), **values}
        with open(self.path, "a") as f:
            f.write(json.dumps(record) + "\n")
        if event in self.silent:
            return
        shown = " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in values.items())
        print(f"[{event}] {shown}", file=sys.stderr, flush=True)


@dataclass
class _Run:
    """One training run's model, optimiser and counters, shared by its steps, validations and checkpoints."""

    conf: dict
    rank: int
    world: int
    out: Path
    log: _Log
    model: StereoGeoNet
    net: torch.nn.Module
    optimizer: torch.optim.Optimizer
    trained: list
    prefixes: tuple[str, ...]
    device: torch.device
    teacher: StereoGeoNet | None
    teacher_sha256: str | None
    step: int
    best: float
    training_data: str = ""
    version: str = ""
    metrics: dict[str, float] = field(default_factory=dict)

    def save(self, path: Path, metrics: dict | None = None) -> None:
        """Write a checkpoint of the run to ``path`` (rank 0 only)."""
        if self.rank != 0:
            return
        save_checkpoint(
            path, self.model, self.step, optimizer=self.optimizer.state_dict(), best=self.best,
            metrics=metrics or {}, train_conf=json.loads(json.dumps(self.conf, default=str)),
            training_data=self.training_data, model_version=self.version,
            input_short_side=int(self.conf["input_short_side"]),
            **({"teacher_sha256": self.teacher_sha256} if self.teacher_sha256 else {}),
        )  # fmt: skip

    def train_step(self, batch: dict) -> tuple[dict, bool]:
        """One optimiser step on ``batch`` (skipped where the gradient is not finite); returns the loss
        terms and whether the batch was a wide one."""
        conf = self.conf
        for group in self.optimizer.param_groups:
            group["lr"] = lr_at(self.step, conf)
        outputs = self.net(batch["left"], batch["right"])
        held, is_wide = None, int(batch["size_index"][0]) >= len(conf["sizes"])
        # A wide batch has no teacher: wide frames are what the fine-tune corrects the teacher's reading
        # of, so its panorama crops are held to their ground truth alone (docs/network.md, "Wide frames
        # in training").
        if self.teacher is not None and not is_wide:
            with torch.no_grad():
                held = self.teacher(batch["left"], batch["right"])
        losses = compute_losses(
            outputs, batch, conf["loss"], with_refiner=self.step >= conf["refiner_start"], teacher=held
        )
        self.optimizer.zero_grad(set_to_none=True)
        losses["total"].backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(self.trained, conf["clip_grad"])
        if torch.isfinite(grad_norm):
            self.optimizer.step()
        self.step += 1
        return losses, is_wide

    def validate_and_keep_best(self, val: FolderPairs) -> None:
        """Validate, log the metrics, and write OUT/best.pt when the camera errors are the lowest yet."""
        conf = self.conf
        self.metrics = validate(self.model, val, conf["val_count"], int(conf["input_short_side"]))
        set_training(self.model, self.prefixes)
        self.log("val", step=self.step, **self.metrics)
        score = self.metrics["roll_median"] + self.metrics["pitch_median"] + self.metrics["vfov_median"]
        if score < self.best:
            self.best = score
            self.save(self.out / "best.pt", self.metrics)


def train(conf: dict) -> dict:
    """Train; returns the last validation metrics (empty without a validation set)."""
    conf = resolve(default_conf, conf)
    rank, world = _distributed()
    torch.set_num_threads(int(conf["threads"]))
    torch.manual_seed(conf["seed"])
    out = Path(conf["out"])
    out.mkdir(parents=True, exist_ok=True)
    log = _Log(out, rank == 0)
    run = _prepare_run(conf, rank, world, out, log)
    dataset, loader, has_wide = _training_loader(conf, rank, world, run.step)
    val = FolderPairs(conf["val"]) if conf["val"] and rank == 0 else None
    run.training_data = _training_data_description(conf)
    run.version = conf["model_version"] or out.name
    log(
        "start",
        step=run.step,
        steps=conf["steps"],
        pairs=len(dataset),
        world=world,
        batch_size=conf["batch_size"],
    )
    started = _run_steps(run, loader, val, has_wide)
    if conf.get("dump_replica"):
        torch.save(run.model.state_dict(), Path(conf["dump_replica"]) / f"rank{rank}.pt")
    log("done", step=run.step, seconds=time.monotonic() - started)
    if world > 1:
        dist.barrier()
        dist.destroy_process_group()
    return run.metrics


def _prepare_run(conf: dict, rank: int, world: int, out: Path, log: _Log) -> _Run:
    """The student on its device with its optimiser, started from ``init`` or resumed, and the teacher."""
    model, prefixes, trained = _student(conf)
    device = _device(conf["device"])
    model.to(device)
    optimizer = torch.optim.AdamW(trained, lr=conf["lr"], weight_decay=conf["weight_decay"])
    step, best, checkpoint = _starting_point(conf, model, optimizer, out / "latest.pt", log)
    set_training(model, prefixes)
    teacher, teacher_sha256 = _teacher(conf, checkpoint, prefixes, device, log)
    net: torch.nn.Module = model
    if world > 1:
        net = torch.nn.parallel.DistributedDataParallel(model)
    return _Run(
        conf, rank, world, out, log, model, net, optimizer, trained, prefixes, device, teacher,
        teacher_sha256, step, best,
    )  # fmt: skip


def _student(conf: dict) -> tuple[StereoGeoNet, tuple[str, ...], list]:
    """The model to train, the ``train_only`` prefixes and the parameters that train (the rest frozen)."""
    # ImageNet weights for the encoder unless a checkpoint supplies every weight (init)
    model = StereoGeoNet({**conf["model"], "pretrained": not conf["init"]})
    if conf["loss"].get("depth_weight", 0) > 0 and model.depth_head is None:
        raise StereoGeoError(
            'loss depth_weight > 0 needs a model with a depth head ("model": {"depth_head": true})'
        )
    prefixes = tuple(conf["train_only"])
    trained = [p for n, p in model.named_parameters() if not prefixes or n.startswith(prefixes)]
    if not trained:
        raise StereoGeoError(f"train_only {list(prefixes)} matches no parameter of the model")
    if prefixes:
        for name, param in model.named_parameters():
            param.requires_grad_(name.startswith(prefixes))
    return model, prefixes, trained


def _starting_point(
    conf: dict, model: StereoGeoNet, optimizer: torch.optim.Optimizer, latest: Path, log: _Log
) -> tuple[int, float, dict]:
    """Load the ``init`` weights, or with ``resume`` the state of ``latest``; returns the step, the best
    validation score and the resumed checkpoint (empty when not resumed)."""
    step, best, checkpoint = 0, math.inf, {}
    if conf["init"] and not (conf.get("resume") and latest.is_file()):
        fresh = init_from_checkpoint(model, conf["init"])
        log(
            "init",
            checkpoint=str(conf["init"]),
            fresh=len(fresh),
            fresh_modules=sorted({n.rsplit(".", 2)[0] for n in fresh}),
        )
    if conf.get("resume") and latest.is_file():
        loaded, checkpoint = load_checkpoint(latest)
        model.load_state_dict(loaded.state_dict())
        optimizer.load_state_dict(checkpoint["optimizer"])
        step, best = int(checkpoint["step"]), float(checkpoint.get("best", math.inf))
        log("resume", step=step)
    return step, best, checkpoint


def _teacher(
    conf: dict, checkpoint: dict, prefixes: tuple[str, ...], device: torch.device, log: _Log
) -> tuple[StereoGeoNet | None, str | None]:
    """The frozen teacher and its file's sha256 when the loss has a teacher weight, else (None, None); a
    resumed run must have the teacher file it started with."""
    if not conf["loss"].get("teacher_weight", 0) > 0:
        return None, None
    if not conf["teacher"]:
        raise StereoGeoError('loss teacher_weight > 0 needs a teacher checkpoint ("teacher": PATH)')
    teacher_sha256 = file_sha256(conf["teacher"])
    started_with = checkpoint.get("teacher_sha256")
    if started_with and started_with != teacher_sha256:
        # e.g. a teacher at models/stereogeo.pt, replaced by the model this run was fine-tuning from
        raise StereoGeoError(
            f"the teacher {conf['teacher']} is not the file this run started with (sha256 "
            f"{teacher_sha256[:12]}, was {started_with[:12]}): resume with that file as the teacher"
        )
    teacher, _ = load_checkpoint(conf["teacher"])
    teacher.to(device)
    teacher.requires_grad_(False)
    # The teacher runs in the student's modes (batch statistics where the student trains), on the
    # whole batch, so before the first step the two agree exactly and the loss holds the function.
    set_training(teacher, prefixes)
    log("teacher", checkpoint=str(conf["teacher"]))
    return teacher, teacher_sha256


def _training_loader(
    conf: dict, rank: int, world: int, step: int
) -> tuple[TrainingPairs, torch.utils.data.DataLoader, bool]:
    """The training pairs, the loader of this rank's batches from ``step`` on, and whether there are wide
    frames."""
    sources, wide_sources = _sources(conf), [FolderPairs(d) for d in conf["wide_data"]]
    sizes = list(conf["sizes"]) + (list(conf["wide_sizes"]) if wide_sources else [])
    free = set(range(len(conf["data"]), len(conf["data"]) + len(conf["teacher_free_data"])))
    teacher_free = [i in free for i in range(len(sources) + len(wide_sources))]
    dataset = TrainingPairs(
        sources + wide_sources, sizes, conf["grey_share"], conf["seed"], conf["sharpness_share"], teacher_free
    )
    wide = None
    if wide_sources:
        wide = (sum(len(s) for s in sources), len(conf["wide_sizes"]), float(conf["wide_share"]))
    sampler = SizedBatches(
        len(dataset), conf["batch_size"], len(conf["sizes"]), conf["seed"], rank, world, step, wide
    )
    loader = torch.utils.data.DataLoader(
        dataset, batch_sampler=sampler, num_workers=conf["workers"],
        persistent_workers=conf["workers"] > 0, prefetch_factor=4 if conf["workers"] > 0 else None,
    )  # fmt: skip
    return dataset, loader, bool(wide_sources)


def _training_data_description(conf: dict) -> str:
    """The training data as the checkpoint records it: the folders, marked by their role, and the renders."""
    return ", ".join(
        [str(d) for d in conf["data"]]
        + [f"{d} (no teacher)" for d in conf["teacher_free_data"]]
        + ([f"{conf['render']} rendered"] if conf["render"] else [])
        + [f"{d} (wide)" for d in conf["wide_data"]]
    )


def _run_steps(
    run: _Run, loader: torch.utils.data.DataLoader, val: FolderPairs | None, has_wide: bool
) -> float:
    """Train until ``steps`` under a progress bar, with progress lines, validations and checkpoints;
    returns the ``time.monotonic()`` at which training started."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    conf, log, latest = run.conf, run.log, run.out / "latest.pt"
    interactive = run.rank == 0 and sys.stderr.isatty()
    if interactive:
        log.silent.add("train")
    columns = (
        TextColumn("step {task.completed}/{task.total}"), BarColumn(), TextColumn("{task.fields[info]}"),
        TimeRemainingColumn(),
    )  # fmt: skip
    last_save, started, seen, wide_seen = time.monotonic(), time.monotonic(), 0, 0
    running: dict[str, float] = {}
    iterator = iter(loader)
    with Progress(*columns, console=Console(stderr=True), disable=not interactive) as bar:
        task = bar.add_task("train", total=conf["steps"], completed=run.step, info="")
        while run.step < conf["steps"]:
            batch = {k: v.to(run.device) if torch.is_tensor(v) else v for k, v in next(iterator).items()}
            losses, is_wide = run.train_step(batch)
            wide_seen += is_wide
            seen += batch["left"].shape[0] * run.world
            for k, v in _to_float(losses).items():
                running[k] = 0.9 * running.get(k, v) + 0.1 * v
            bar.update(task, completed=run.step, info=f"loss {running['total']:.3f}")
            if run.step % conf["log_every"] == 0 or run.step == 1:
                rate = seen / max(time.monotonic() - started, 1e-9)
                extra = {"wide_batches": wide_seen} if has_wide else {}
                log("train", step=run.step, lr=lr_at(run.step, conf), pairs_per_s=rate, **extra, **running)
            if val is not None and (run.step % conf["val_every"] == 0 or run.step == conf["steps"]):
                run.validate_and_keep_best(val)
            due = time.monotonic() - last_save > 60 * conf["checkpoint_minutes"] or run.step == conf["steps"]
            if _agree(due, run.world):
                _sync_buffers(run.model, run.world)
                run.save(latest, run.metrics)
                last_save = time.monotonic()
    return started


def parse_args(argv: list[str] | None = None) -> dict:
    """Command-line arguments (for torchrun) → a training config: defaults < --config file < flags."""
    parser = argparse.ArgumentParser(prog="stereogeo train", description=__doc__)
    parser.add_argument("--config", type=Path, help="a JSON file with any of the training settings")
    parser.add_argument("--data", action="append", help="a dataset folder (repeatable)")
    parser.add_argument("--resume", action="store_true", help="continue from OUT/latest.pt if it exists")
    parser.add_argument("--dump-replica", help=argparse.SUPPRESS)
    for key, value in default_conf.items():
        if isinstance(value, (list, dict)):  # lists and dicts come from the --config file
            continue
        kind = type(value) if value is not None else str
        parser.add_argument(f"--{key.replace('_', '-')}", type=kind, default=None, help=SETTINGS[key][1])
    args = parser.parse_args(argv)
    conf = dict(default_conf)
    if args.config:
        conf.update(json.loads(args.config.read_text()))
    for key, value in vars(args).items():
        if key in ("config",) or value is None:
            continue
        conf[key] = value
    unknown = set(conf["loss"]) - set(loss_defaults)
    if unknown:
        raise StereoGeoError(f"unknown loss settings: {sorted(unknown)}")
    for share in ("grey_share", "sharpness_share"):
        if not 0.0 <= float(conf[share]) <= 1.0:
            raise StereoGeoError(f"{share} must be between 0 and 1, got {conf[share]}")
    if not 0.0 <= float(conf["wide_share"]) < 1.0:
        raise StereoGeoError(f"wide_share must be at least 0 and below 1, got {conf['wide_share']}")
    return conf


def main(argv: list[str] | None = None) -> None:
    try:
        train(parse_args(argv))
    except StereoGeoError as error:
        print(f"error: {error}", file=sys.stderr)
        sys.exit(error.exit_code)


if __name__ == "__main__":
    main()
