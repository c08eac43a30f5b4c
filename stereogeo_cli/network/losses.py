"""Training losses: field errors, camera errors after the unrolled refiner, and pose errors.

Weights live in :data:`default_conf`; the training config overrides them.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from stereogeo_cli.network.data import MATCH_STRIDE
from stereogeo_cli.network.model import OUTPUT_STRIDE
from stereogeo_cli.network.runtime import cell_pixel_coordinates
from stereogeo_cli.refine import initial_estimate
from stereogeo_cli.refine.torch_twin import refine_batch
from stereogeo_cli.settings import resolve

default_conf = {
    "up_weight": 1.0,  # L1 of the up-vector field
    "latitude_weight": 2.0,  # L1 of the latitude field (radians); it carries the focal length
    "confidence_weight": 0.1,  # BCE of each confidence against exp(-error / scale) of its field
    "confidence_scale": 0.05,  # error (unit-vector distance or radians) at which the target is 1/e
    "camera_weight": 1.0,  # L1 of roll, pitch and vFoV (radians) after the unrolled refiner
    "refiner_steps": 5,  # unrolled LM steps of the torch twin during training
    "refiner_stride": 2,  # use every n-th field cell in each direction for the refiner
    "rotation_weight": 5.0,  # smooth L1 of the relative rotation angle (radians)
    "translation_weight": 1.0,  # smooth L1 of log |T| ratio, of T/|T| and of the angle
    "rotation_beta": 0.01,  # where the smooth L1 turns from quadratic to linear, radians
    "translation_beta": 0.02,  # the same for the direction terms (T/|T| and the angle, radians)
    "scale_beta": 0.05,  # the same for log(|T_pred| / |T_true|)
    "epipolar_weight": 0.0,  # robust Sampson distance of the pose head's soft matches to the true epipolars
    "epipolar_scale": 0.03,  # its scale, in units of half the short side (about 3 px at 224)
    # With depth maps (make-data --depth): each left cell's soft match against its true right position
    # (robust, as the epipolar loss, which cannot see a match sliding along its epipolar line) ...
    "match_weight": 0.0,
    "match_scale": 0.03,
    # ... and each cell's vote against log |T| − log |its true parallax| (smooth L1 of the log), where that
    # parallax (true position minus a point at infinity's) is at least ``vote_min_parallax``.
    "vote_weight": 0.0,
    # the depth head (model option depth_head): Laplace negative log-likelihood of each cell's log depth over
    # focal, with its predicted spread, where the depth maps give one (make-data --depth)
    "depth_weight": 0.0,
    "vote_min_parallax": 0.02,
    "vote_beta": 0.1,
    # The head's point at infinity against the rotation's true one (mean over the cells; smooth L1).
    "infinity_weight": 0.0,
    "infinity_beta": 0.01,
    # With a teacher (train setting ``teacher``): L1 of the student's up and latitude fields (the latter
    # ×2, as in the field losses) against the frozen teacher's on the pure-rotation pairs, the crops of
    # real panoramas: a fine-tune on renders is held to the teacher's reading of real photographs.
    "teacher_weight": 0.0,
    # Real photographs without gravity (make-data --photos): L1 of the vFoV (radians) after the unrolled
    # refiner, the only truth they have; with gravity they take the field and camera losses as renders do.
    "photo_weight": 0.0,
}


def cell_centres(
    height: int, width: int, stride: int = OUTPUT_STRIDE, device: torch.device | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel centres (x, y) [h x w] of the field cells of an image (height x width), as float32 tensors
    on ``device`` (default: the CPU)."""
    x, y = cell_pixel_coordinates(height // stride, width // stride, stride)
    return torch.from_numpy(x).float().to(device), torch.from_numpy(y).float().to(device)


def ground_truth_fields(gravity: torch.Tensor, focal: torch.Tensor, width: int, height: int):
    """Up [B x 2 x h x w] and latitude [B x h x w] at the cell centres of images (width x height)."""
    x, y = cell_centres(height, width, device=gravity.device)
    u = (x[None] - width / 2) / focal[:, None, None]
    v = (y[None] - height / 2) / focal[:, None, None]
    g = gravity[:, :, None, None]
    up = F.normalize(torch.stack([g[:, 0] - g[:, 2] * u, g[:, 1] - g[:, 2] * v], dim=1), dim=1)
    sin_lat = (g[:, 0] * u + g[:, 1] * v + g[:, 2]) / torch.sqrt(u * u + v * v + 1)
    return up, torch.asin(sin_lat.clamp(-1, 1))


def quaternion_to_rotation(q: torch.Tensor) -> torch.Tensor:
    """[B x 4] (w, x, y, z) → [B x 3 x 3]."""
    q = F.normalize(q, dim=-1)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(-1, 3, 3)  # fmt: skip


def rotation_angle(R: torch.Tensor) -> torch.Tensor:
    """Angles [B] in radians of rotations [B x 3 x 3], with a gradient that stays finite at 0."""
    cos = ((torch.diagonal(R, dim1=1, dim2=2).sum(-1) - 1) / 2).clamp(-1 + 1e-7, 1 - 1e-7)
    sin = torch.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], -1).norm(
        dim=-1
    )
    return torch.atan2(sin / 2 + 1e-12, cos)


def roll_pitch_vfov(gravity: torch.Tensor, focal: torch.Tensor, height: float):
    g = F.normalize(gravity, dim=-1)
    roll = torch.atan2(-g[:, 0], -g[:, 1])
    pitch = torch.asin(g[:, 2].clamp(-1 + 1e-7, 1 - 1e-7))
    return roll, pitch, 2 * torch.atan(height / (2 * focal))


def _angle_diff(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.atan2(torch.sin(a - b), torch.cos(a - b)).abs()


def refine_views(out: dict, view: str, height: int, width: int, conf: dict):
    """Run the torch twin on a view's predicted fields; returns gravity [B x 3] and focal [B] (pixels)."""
    s = conf["refiner_stride"]
    up = out[f"{view}_up"][:, :, ::s, ::s]
    lat = out[f"{view}_latitude"][:, ::s, ::s]
    c_up = out[f"{view}_up_confidence"][:, ::s, ::s]
    c_lat = out[f"{view}_latitude_confidence"][:, ::s, ::s]
    x, y = cell_centres(height, width, device=up.device)
    x, y = x[::s, ::s].reshape(-1).float(), y[::s, ::s].reshape(-1).float()
    batch = up.shape[0]
    up_flat = up.permute(0, 2, 3, 1).reshape(batch, -1, 2)
    lat_flat, cu, cl = lat.reshape(batch, -1), c_up.reshape(batch, -1), c_lat.reshape(batch, -1)
    # the starts come from NumPy: the batch crosses to the host once
    up_np, lat_np, cu_np, cl_np, x_np, y_np = (
        t.detach().double().cpu().numpy() for t in (up_flat, lat_flat, cu, cl, x, y)
    )
    starts = [
        initial_estimate(up_np[b], lat_np[b], cu_np[b], cl_np[b], x_np, y_np, width, height)
        for b in range(batch)
    ]
    g0 = torch.tensor(np.stack([s_[0] for s_ in starts]), dtype=up.dtype, device=up.device)
    f0 = torch.tensor([s_[1] for s_ in starts], dtype=up.dtype, device=up.device)
    size = torch.tensor([[width, height]] * batch, dtype=up.dtype, device=up.device)
    return refine_batch(up_flat, lat_flat, cu, cl, x, y, size, g0, f0, conf={"steps": conf["refiner_steps"]})


def epipolar_loss(
    xy_left: torch.Tensor,
    xy_right: torch.Tensor,
    focal: torch.Tensor,
    R: torch.Tensor,
    T: torch.Tensor,
    half_short: float,
    scale: float,
) -> torch.Tensor:
    """Mean robust Sampson distance ``log(1 + (d / scale)²)`` of correspondences to the true epipolar lines.

    ``xy_left``, ``xy_right`` [B x N x 2]: points relative to the image centre in units of ``half_short``
    pixels (the pose head's cell coordinates), and d in the same units; ``focal`` [B x 2] pixels of the left
    and right view; R, T the rig (``X_right = R X_left + T``). The principal point is the centre, as in the
    training cuts. d is the torch twin of :func:`stereogeo_cli.fuse.sampson_errors` (a test holds them equal).
    """
    tx, ty, tz = T.unbind(-1)
    zero = torch.zeros_like(tx)
    skew = torch.stack([zero, -tz, ty, tz, zero, -tx, -ty, tx, zero], dim=-1).reshape(-1, 3, 3)

    def k_inverse(f: torch.Tensor) -> torch.Tensor:  # K⁻¹ of a centred pinhole camera, [B x 3 x 3]
        return torch.diag_embed(torch.stack([1 / f, 1 / f, torch.ones_like(f)], dim=-1))

    F_ = k_inverse(focal[:, 1]).transpose(1, 2) @ skew @ R @ k_inverse(focal[:, 0])
    left, right = (
        torch.cat([xy * half_short, torch.ones_like(xy[..., :1])], dim=-1) for xy in (xy_left, xy_right)
    )
    Fl = left @ F_.transpose(1, 2)  # [B x N x 3]: F @ left point
    Ftr = right @ F_  # Fᵀ @ right point
    algebraic = (right * Fl).sum(-1)
    denom = Fl[..., 0] ** 2 + Fl[..., 1] ** 2 + Ftr[..., 0] ** 2 + Ftr[..., 1] ** 2
    distance2 = algebraic**2 / denom.clamp_min(1e-12)  # pixels²
    return torch.log1p(distance2 / (half_short * scale) ** 2).mean()


def match_losses(out: dict, batch: dict, conf: dict) -> dict[str, torch.Tensor]:
    """The pose head's losses against the true correspondences (:func:`network.data.match_targets`):
    ``match`` and ``vote`` where depth made them valid, ``infinity`` for every pair with a pose; only the
    terms whose weight is not 0."""
    losses: dict[str, torch.Tensor] = {}
    if out["pose_match_left"].shape != batch["infinity_xy"].shape:
        raise ValueError(
            f"the match targets are for stride-{MATCH_STRIDE} cells; this pose head matches "
            f"{out['pose_match_left'].shape[1]} cells, the targets have {batch['infinity_xy'].shape[1]}"
        )
    pose = batch["has_pose"]
    if conf["infinity_weight"] > 0 and pose.any():
        true_shift = (batch["infinity_xy"] - out["pose_match_left"]).mean(1)[pose]  # [B' x 2]
        losses["infinity"] = F.smooth_l1_loss(
            out["pose_infinity"][pose], true_shift, beta=conf["infinity_beta"], reduction="sum"
        ) / (2 * len(true_shift))
    valid = batch["match_valid"]
    if conf["match_weight"] > 0 and valid.any():
        d2 = ((out["pose_match_right"] - batch["match_xy"]) ** 2).sum(-1)[valid]
        losses["match"] = torch.log1p(d2 / conf["match_scale"] ** 2).mean()
    if conf["vote_weight"] > 0:
        parallax = (batch["match_xy"] - batch["infinity_xy"]).norm(dim=-1)  # [B x N]
        usable = valid & batch["has_translation"][:, None] & (parallax >= conf["vote_min_parallax"])
        if usable.any():
            log_length = torch.log(batch["T"].norm(dim=-1).clamp_min(1e-3))[:, None].expand_as(parallax)
            target = (log_length - torch.log(parallax + 1e-3))[usable]
            vote = out["pose_vote"][..., 0][usable]
            losses["vote"] = F.smooth_l1_loss(vote, target, beta=conf["vote_beta"])
    return losses


def teacher_loss(out: dict, teacher: dict, mask: torch.Tensor) -> torch.Tensor:
    """Mean L1 of the student's fields against a frozen teacher's (both outputs of the whole batch) on the
    samples of ``mask`` [B]: the up vectors' (summed over x, y) plus twice the latitudes' (radians), both
    views. Zero (with a gradient path) when ``mask`` is empty."""
    if not mask.any():
        return out["left_latitude"].sum() * 0.0
    terms = []
    for view in ("left", "right"):
        up, lat = f"{view}_up", f"{view}_latitude"
        terms.append((out[up][mask] - teacher[up][mask]).abs().sum(1).mean())
        terms.append(2.0 * (out[lat][mask] - teacher[lat][mask]).abs().mean())
    return torch.stack(terms).sum() / 2.0


def compute_losses(
    out: dict, batch: dict, conf: dict | None = None, with_refiner: bool = True, teacher: dict | None = None
) -> dict:
    """All loss terms (scalars) and ``total``, for model outputs ``out`` on a training ``batch``.

    ``teacher``: a frozen teacher's outputs on the batch, held to on its pure-rotation pairs
    (``teacher_weight``)."""
    conf = resolve(default_conf, conf)
    has_gravity = torch.isfinite(batch["gravity"]).all(-1)  # [B x 2]
    losses = _field_losses(out, batch, conf, with_refiner, has_gravity)
    losses.update(_pose_losses(out, batch, conf))
    if "pose_infinity" in out and "infinity_xy" in batch:
        losses.update(match_losses(out, batch, conf))
    losses.update(_depth_loss(out, batch, conf))
    if teacher is not None and conf["teacher_weight"] > 0:
        losses["teacher"] = teacher_loss(out, teacher, _teacher_mask(batch, has_gravity))
    losses["total"] = _weighted_total(losses, conf)
    return losses


def _field_losses(
    out: dict, batch: dict, conf: dict, with_refiner: bool, has_gravity: torch.Tensor
) -> dict[str, torch.Tensor]:
    """The up, latitude, confidence, camera and photo terms, each the mean over the views that have it."""
    height, width = batch["left"].shape[-2:]
    terms: dict[str, list[torch.Tensor]] = {
        k: [] for k in ("up", "latitude", "confidence", "camera", "photo")
    }
    for v, view in enumerate(("left", "right")):
        focal_only = ~has_gravity[:, v] & torch.isfinite(batch["focal"][:, v])
        if with_refiner and conf["photo_weight"] > 0 and focal_only.any():
            sub = {k: t[focal_only] for k, t in out.items() if k.startswith(view)}
            _, f_hat = refine_views(sub, view, height, width, conf)
            fov_hat = 2 * torch.atan(height / (2 * f_hat))
            fov_gt = 2 * torch.atan(height / (2 * batch["focal"][:, v][focal_only]))
            terms["photo"].append((fov_hat - fov_gt).abs().mean())
        mask = has_gravity[:, v]
        if mask.any():
            _gravity_terms(terms, out, batch, conf, v, mask, with_refiner)
    return {name: torch.stack(values).mean() for name, values in terms.items() if values}


def _gravity_terms(
    terms: dict[str, list[torch.Tensor]],
    out: dict,
    batch: dict,
    conf: dict,
    v: int,
    mask: torch.Tensor,
    with_refiner: bool,
) -> None:
    """Append view ``v``'s field and confidence terms on the samples of ``mask`` (those with gravity), and
    its camera term after the unrolled refiner."""
    view = ("left", "right")[v]
    height, width = batch["left"].shape[-2:]
    g = batch["gravity"][:, v][mask]
    f = batch["focal"][:, v][mask]
    up_gt, lat_gt = ground_truth_fields(g, f, width, height)
    up_err = (out[f"{view}_up"][mask] - up_gt).abs().sum(1)
    lat_err = (out[f"{view}_latitude"][mask] - lat_gt).abs()
    terms["up"].append(up_err.mean())
    terms["latitude"].append(lat_err.mean())
    scale = conf["confidence_scale"]
    for name, err in (("up_confidence", up_err), ("latitude_confidence", lat_err)):
        target = torch.exp(-err.detach() / scale)
        terms["confidence"].append(
            F.binary_cross_entropy(out[f"{view}_{name}"][mask].clamp(1e-6, 1 - 1e-6), target)
        )
    if with_refiner and conf["camera_weight"] > 0:
        sub = {k: t[mask] for k, t in out.items() if k.startswith(view)}
        g_hat, f_hat = refine_views(sub, view, height, width, conf)
        r_hat, p_hat, fov_hat = roll_pitch_vfov(g_hat, f_hat, height)
        r_gt, p_gt, fov_gt = roll_pitch_vfov(g, f, height)
        camera = _angle_diff(r_hat, r_gt) + (p_hat - p_gt).abs() + (fov_hat - fov_gt).abs()
        terms["camera"].append(camera.mean())


def _pose_losses(out: dict, batch: dict, conf: dict) -> dict[str, torch.Tensor]:
    """The pose head's rotation and translation terms, and its epipolar term where it has one."""
    losses: dict[str, torch.Tensor] = {}
    height, width = batch["left"].shape[-2:]
    # Huber losses divided by their threshold (smooth L1): a unit gradient for large errors, so the
    # pose terms (radians, metres, often < 0.1) are not dwarfed by the field terms.
    pose = batch["has_pose"]
    if pose.any():
        R_hat = quaternion_to_rotation(out["quaternion"][pose])
        angle = rotation_angle(R_hat @ batch["R"][pose].transpose(1, 2))
        losses["rotation"] = F.smooth_l1_loss(angle, torch.zeros_like(angle), beta=conf["rotation_beta"])
    trans = batch["has_translation"]
    if trans.any():
        t_hat, t_gt = out["translation"][trans], batch["T"][trans]
        d_hat, d_gt = F.normalize(t_hat, dim=-1), F.normalize(t_gt, dim=-1)
        cos = (d_hat * d_gt).sum(-1).clamp(-1 + 1e-7, 1 - 1e-7)
        beta = conf["translation_beta"]
        # The length in log space: a relative error, the same for a 5 cm and an 80 cm rig.
        log_ratio = torch.log(t_hat.norm(dim=-1).clamp_min(1e-3) / t_gt.norm(dim=-1).clamp_min(1e-3))
        losses["translation"] = (
            F.smooth_l1_loss(log_ratio, torch.zeros_like(log_ratio), beta=conf["scale_beta"])
            + F.smooth_l1_loss(d_hat, d_gt, beta=beta)
            + F.smooth_l1_loss(torch.acos(cos), torch.zeros_like(cos), beta=beta)
        )
    if "pose_match_left" in out and conf["epipolar_weight"] > 0 and trans.any():
        losses["epipolar"] = epipolar_loss(
            out["pose_match_left"][trans], out["pose_match_right"][trans], batch["focal"][trans],
            batch["R"][trans], batch["T"][trans], min(height, width) / 2, conf["epipolar_scale"],
        )  # fmt: skip
    return losses


def _depth_loss(out: dict, batch: dict, conf: dict) -> dict[str, torch.Tensor]:
    """``depth``: the depth head's Laplace negative log-likelihood over the cells with a true depth, when
    ``depth_weight`` is not 0 and the batch has depth maps (empty otherwise)."""
    if conf["depth_weight"] > 0 and "left_depth" not in out:
        raise ValueError(
            "the depth loss (depth_weight > 0) needs a model with a depth head (depth_head: true)"
        )
    if not (conf["depth_weight"] > 0 and "depth_left" in batch):
        return {}
    nll = []
    for view in ("left", "right"):
        target = batch[f"depth_{view}"]
        valid = torch.isfinite(target)
        if valid.any():
            spread = out[f"{view}_depth_spread"][valid].clamp(-5.0, 3.0)
            error = (out[f"{view}_depth"][valid] - target[valid]).abs()
            nll.append((error * torch.exp(-spread) + spread).mean())
    return {"depth": torch.stack(nll).mean()} if nll else {}


def _teacher_mask(batch: dict, has_gravity: torch.Tensor) -> torch.Tensor:
    """The samples held to the teacher [B]: the pure-rotation pairs with gravity, the crops of real
    panoramas (not photographs, which are learnt from their own truth, nor pairs of the train setting
    teacher_free_data)."""
    held = ~batch["has_translation"] & has_gravity.all(-1)
    if "teacher_free" in batch:
        held = held & ~batch["teacher_free"]
    return held


def _weighted_total(losses: dict[str, torch.Tensor], conf: dict) -> torch.Tensor:
    """The sum of the loss terms, each times its weight, in the order of ``losses``."""
    weights = {
        "teacher": conf["teacher_weight"],
        "epipolar": conf["epipolar_weight"], "match": conf["match_weight"], "vote": conf["vote_weight"],
        "infinity": conf["infinity_weight"], "depth": conf["depth_weight"],
        "up": conf["up_weight"], "latitude": conf["latitude_weight"], "confidence": conf["confidence_weight"],
        "camera": conf["camera_weight"], "photo": conf["photo_weight"], "rotation": conf["rotation_weight"],
        "translation": conf["translation_weight"],
    }  # fmt: skip
    return sum(weights[k] * v for k, v in losses.items())
