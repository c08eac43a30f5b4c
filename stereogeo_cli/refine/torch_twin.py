"""The torch twin of the refiner: the same LM maths, batched and unrolled, so training can back-propagate.

It mirrors :mod:`stereogeo_cli.refine.lm`, :mod:`stereogeo_cli.geometry.fields` and the package's one LM
loop (:func:`stereogeo_cli.refine.levenberg.levenberg_marquardt`: the same damped step, the same
acceptance, the same damping schedule) step for step; tests hold them equal. Differences, both for
training: a fixed number of steps with no early stop (a rejected step is masked with ``torch.where``, which
keeps gradients), and a plain squared loss by default (``huber_scale=None``), as GeoCalib trains. Only
training imports this module.
"""

from __future__ import annotations

import math

import torch

from stereogeo_cli.refine.levenberg import DIAGONAL_FLOOR, LAMBDA_DOWN, LAMBDA_FLOOR, LAMBDA_UP
from stereogeo_cli.settings import resolve

default_conf = {
    "steps": 10,  # unrolled LM steps
    "lambda_init": 0.1,  # initial damping (the refiner's; the schedule is refine/levenberg.py's)
    "huber_scale": None,  # None: squared loss; a float: the refiner's scaled Huber
    "curvature_switch": 0.1,  # as the refiner's (refine/lm.py)
    "min_vfov_deg": 5.0,  # log f is clamped so the vFoV stays within these bounds
    "max_vfov_deg": 150.0,
}


def tangent_basis(g: torch.Tensor) -> torch.Tensor:
    """[B x 3] unit up vectors → [B x 3 x 2] tangent bases (columns: d g/d pitch, d g/d roll / cos pitch)."""
    norm = torch.sqrt(g[:, 0] ** 2 + g[:, 1] ** 2).clamp_min(1e-12)
    hx, hy = g[:, 0] / norm, g[:, 1] / norm
    e_pitch = torch.stack([-hx * g[:, 2], -hy * g[:, 2], norm], dim=-1)
    e_roll = torch.stack([hy, -hx, torch.zeros_like(hx)], dim=-1)
    return torch.stack([e_pitch, e_roll], dim=-1)


def retract_on_sphere(g: torch.Tensor, delta: torch.Tensor, basis: torch.Tensor) -> torch.Tensor:
    """Exponential map on the sphere: g [B x 3] moved by tangent steps delta [B x 2]."""
    step = (basis @ delta.unsqueeze(-1)).squeeze(-1)
    angle = step.norm(dim=-1, keepdim=True)
    safe = angle.clamp_min(1e-15)
    moved = torch.cos(angle) * g + torch.sin(angle) * step / safe
    return torch.where(angle > 1e-15, moved, g)


def fields_and_jacobian_factors(g, log_f, x, y, cx, cy):
    """Batched twin of :func:`stereogeo_cli.geometry.fields.fields_and_jacobian_factors`.

    g [B x 3], log_f [B], x, y [B x N], cx, cy [B] → up [B x N x 2], sin_lat [B x N], perp [B x N x 2],
    k [B x N x 3], J_lat [B x N x 3].
    """
    B_ = tangent_basis(g)
    f = torch.exp(log_f)[:, None]
    u, v = (x - cx[:, None]) / f, (y - cy[:, None]) / f
    gx, gy, gz = g[:, 0:1], g[:, 1:2], g[:, 2:3]
    a_x, a_y = gx - gz * u, gy - gz * v
    a_norm = torch.sqrt(a_x * a_x + a_y * a_y)
    up = torch.stack([a_x, a_y], dim=-1) / a_norm[..., None]
    perp = torch.stack([-up[..., 1], up[..., 0]], dim=-1)
    perp_uv = perp[..., 0] * u + perp[..., 1] * v
    dg = torch.stack([perp[..., 0], perp[..., 1], -perp_uv], dim=-1) @ B_  # [B x N x 2]
    k = torch.cat([dg / a_norm[..., None], (gz * perp_uv / a_norm)[..., None]], dim=-1)
    p_norm = torch.sqrt(u * u + v * v + 1.0)
    ray = torch.stack([u, v, torch.ones_like(u)], dim=-1) / p_norm[..., None]
    sin_lat = (ray @ g.unsqueeze(-1)).squeeze(-1)
    ray_uv = ray[..., 0] * u + ray[..., 1] * v
    J_lat = torch.cat([ray @ B_, ((-(gx * u + gy * v) + sin_lat * ray_uv) / p_norm)[..., None]], dim=-1)
    return up, sin_lat, perp, k, J_lat


def _robust(s: torch.Tensor, scale: float | None) -> tuple[torch.Tensor, torch.Tensor]:
    if scale is None:
        return s, torch.ones_like(s)
    a2 = scale * scale
    root = torch.sqrt(s.clamp_min(a2))
    return torch.where(s <= a2, s, 2.0 * scale * root - a2), torch.where(
        s <= a2, torch.ones_like(s), scale / root
    )


def _cost_and_normal_equations(g, log_f, data, scale, near):
    """The refiner's cost, H, gradient and damping diagonal, batched; ``near`` [B]: H with the Huber loss's
    own curvature where True (refine/lm.py, ``_Problem.normal_equations``)."""
    up, sin_lat, perp, k, J_lat = fields_and_jacobian_factors(
        g, log_f, data["x"], data["y"], data["cx"], data["cy"]
    )
    r_up = data["up"] - up
    r_lat = data["sin_lat"] - sin_lat
    s_up = (r_up * r_up).sum(-1)
    s_lat = r_lat * r_lat
    rho_up, d_up = _robust(s_up, scale)
    rho_lat, d_lat = _robust(s_lat, scale)
    cost = ((data["c_up"] * rho_up).sum(-1) + (data["c_lat"] * rho_lat).sum(-1)) / data["n"]
    w_up, w_lat = data["c_up"] * d_up, data["c_lat"] * d_lat
    r_perp = (perp * r_up).sum(-1)
    wk, wJ_lat = k * w_up[..., None], J_lat * w_lat[..., None]
    H = wk.transpose(1, 2) @ k + wJ_lat.transpose(1, 2) @ J_lat
    grad = -((wk * r_perp[..., None]).sum(1) + (wJ_lat * r_lat[..., None]).sum(1))
    damping = torch.diagonal(H, dim1=1, dim2=2)
    if scale is not None:  # a squared loss has no outer part: its two Hessians are one
        along = r_perp**2 / s_up.clamp_min(1e-300)
        across = torch.where(s_up > scale**2, 1.0 - along, torch.ones_like(along))
        curved = (wk * across[..., None]).transpose(1, 2) @ k
        curved = curved + (wJ_lat * (s_lat <= scale**2)[..., None]).transpose(1, 2) @ J_lat
        H = torch.where(near[:, None, None], curved, H)
    return cost, H, grad, damping


def _cost(g, log_f, data, scale):
    f = torch.exp(log_f)[:, None]
    u, v = (data["x"] - data["cx"][:, None]) / f, (data["y"] - data["cy"][:, None]) / f
    gx, gy, gz = g[:, 0:1], g[:, 1:2], g[:, 2:3]
    a = torch.stack([gx - gz * u, gy - gz * v], dim=-1)
    up = a / a.norm(dim=-1, keepdim=True)
    sin_lat = (gx * u + gy * v + gz) / torch.sqrt(u * u + v * v + 1.0)
    r_up, r_lat = data["up"] - up, data["sin_lat"] - sin_lat
    rho_up, _ = _robust((r_up * r_up).sum(-1), scale)
    rho_lat, _ = _robust(r_lat * r_lat, scale)
    return ((data["c_up"] * rho_up).sum(-1) + (data["c_lat"] * rho_lat).sum(-1)) / data["n"]


def refine_batch(
    up: torch.Tensor,
    latitude: torch.Tensor,
    up_confidence: torch.Tensor,
    latitude_confidence: torch.Tensor,
    x: torch.Tensor,
    y: torch.Tensor,
    image_size: torch.Tensor,
    gravity_init: torch.Tensor,
    focal_init: torch.Tensor,
    conf: dict | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Unrolled LM for a batch of cameras, differentiable with respect to the fields and confidences.

    Args:
        up: [B x N x 2] up field samples; latitude: [B x N] radians; confidences: [B x N].
        x, y: [B x N] (or [N]) pixel coordinates of the samples; image_size: [B x 2] (width, height) in
            pixels, the principal point at its centre.
        gravity_init: [B x 3] start; focal_init: [B] start in pixels (e.g. from
            :func:`stereogeo_cli.refine.initial_estimate`, which needs no gradient).
    Returns:
        gravity [B x 3] (unit up vectors) and focal [B] in pixels.
    """
    conf = resolve(default_conf, conf)
    batch = up.shape[0]
    x = x.expand(batch, -1) if x.dim() == 1 else x
    y = y.expand(batch, -1) if y.dim() == 1 else y
    width, height = image_size[:, 0].to(up.dtype), image_size[:, 1].to(up.dtype)
    up = up / up.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    data = {
        "up": up, "sin_lat": torch.sin(latitude), "c_up": up_confidence, "c_lat": latitude_confidence,
        "x": x, "y": y, "cx": width / 2, "cy": height / 2, "n": float(up.shape[1]),
    }  # fmt: skip
    log_f_min = torch.log(height / (2 * math.tan(math.radians(conf["max_vfov_deg"]) / 2)))
    log_f_max = torch.log(height / (2 * math.tan(math.radians(conf["min_vfov_deg"]) / 2)))
    g = gravity_init / gravity_init.norm(dim=-1, keepdim=True)
    log_f = torch.minimum(torch.maximum(torch.log(focal_init.to(up.dtype)), log_f_min), log_f_max)
    lam = torch.full((batch,), conf["lambda_init"], dtype=up.dtype, device=up.device)
    eye = torch.eye(3, dtype=up.dtype, device=up.device)
    scale = conf["huber_scale"]
    near = torch.zeros(batch, dtype=torch.bool, device=up.device)
    for _ in range(conf["steps"]):
        # levenberg_marquardt's loop, batched: the damped step, kept where it lowers the cost
        cost, H, grad, damping = _cost_and_normal_equations(g, log_f, data, scale, near)
        diag = damping + DIAGONAL_FLOOR
        A = H + lam[:, None, None] * diag[:, None, :] * eye
        step = -torch.linalg.solve(A, grad.unsqueeze(-1)).squeeze(-1)
        g_new = retract_on_sphere(g, step[:, :2], tangent_basis(g))
        log_f_new = torch.minimum(torch.maximum(log_f + step[:, 2], log_f_min), log_f_max)
        new = _cost(g_new, log_f_new, data, scale)
        accept = new < cost
        g = torch.where(accept[:, None], g_new, g)
        log_f = torch.where(accept, log_f_new, log_f)
        lam = torch.where(accept, (lam * LAMBDA_DOWN).clamp_min(LAMBDA_FLOOR), lam * LAMBDA_UP).detach()
        near = near | (accept & (cost - new <= conf["curvature_switch"] * cost)).detach()
    return g, torch.exp(log_f)
