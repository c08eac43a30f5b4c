"""The focal length a man-made scene's straight edges give: a Manhattan frame fitted to the line segments.

Walls, shelves, tables, windows and streets are built along three orthogonal directions, one of them
vertical. A camera of focal length f sees each of them converge to a vanishing point ``K d``, and where two
of those points are finite (a room's corner seen obliquely, a street going away) their positions fix f:
orthogonal directions meet at points whose offsets from the principal point satisfy
``(v1 - c)·(v2 - c) = -f²``. A camera looking square at a wall (one point at infinity) says little of f, and
the fit's Hessian says so.

The fit: parameters (log f, the up direction's two tangent angles around the fields' gravity, the frame's
yaw about it); each segment belongs to the direction whose vanishing point it points at best, and its
residual is the distance of its endpoint from the line through its midpoint and that point, in image
pixels, under a Cauchy loss (segments along none of the three directions weigh little). Starts over a
grid of focal lengths around the fields' and of yaws; the best start is refined by Levenberg–Marquardt.

The 1-sigma of log f comes from the fit's Hessian, with every pixel of segment length one independent
measurement. Neighbouring pixels of one edge are not independent, nor the edges of one object, so it is
widened by ``sigma_scale`` and floored at ``sigma_floor``: both measured on held-out renders and
real-panorama crops (docs/refine.md, "Vanishing points"). That sigma says how well the segments fix the
frame, not whether the frame is the scene's: a frame locked onto clutter, a statue or a pattern that is not
Manhattan fits its segments as tightly. Such a frame moves when the edges are detected at another
resolution, and a frame of the scene does not, so :func:`stable_manhattan_focal` fits the frame again to the
segments found at ``stability_scale`` of the detector's resolution and adds the two reads' distance in log f
to the sigma. The pipeline combines the read with the fields' focal length only where the two agree within
``gate_sigmas`` (the lines can lock onto a non-Manhattan pattern).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stereogeo_cli.geometry.camera import principal_point
from stereogeo_cli.geometry.gravity import tangent_basis
from stereogeo_cli.refine.levenberg import Settings, covariance, levenberg_marquardt
from stereogeo_cli.settings import resolve

default_conf = {
    "enabled": True,
    # refine.lines.detect_segments runs on the image reduced to at most this short side (finer than the
    # vertical lines' 256: the vanishing points need the edges' directions to a fraction of a degree)
    "max_short_side": 640,
    "min_length_rel": 0.03,  # shortest segment used, as a fraction of the image diagonal
    "min_segments": 8,
    "loss_scale_px": 1.0,  # Cauchy scale of the residuals, in detector pixels
    "focal_starts": (0.6, 0.8, 1.0, 1.25, 1.6),  # starts, as multiples of the fields' focal length
    "yaw_step_deg": 7.5,  # starts of the frame's yaw in [0°, 90°)
    "iterations": 100,  # Levenberg–Marquardt steps tried (refine/levenberg.py)
    # the Hessian's 1-sigma of log f, widened and floored (module docstring; docs/refine.md, "Vanishing
    # points", "Its sigma")
    "sigma_scale": 3.0,
    "sigma_floor": 0.08,
    # combined with the fields' focal length only within this many combined sigmas of it (pipeline)
    "gate_sigmas": 2.0,
    # the frame is fitted again to the segments found at this fraction of the detector's resolution; the
    # two reads' distance in log f joins the sigma (module docstring; docs/refine.md, "Its sigma")
    "stability_scale": 0.75,
    # not used where the image's edges read a lens (refine/plumb.py) more than this many sigmas from none:
    # the raw chessboard rig's views read 5.0–7.1, Middlebury's pinhole views at most 3.3 (pipeline;
    # docs/refine.md, "Vanishing points", "Where it is not used, and why"); such a camera is raw, and its
    # principal point widens the pose's sigmas even where the matches fit no lens (fuse_relative_pose)
    "lens_sigmas": 4.0,
}

_LOG_F_RANGE = (-5.0, 20.0)  # keeps exp(log f) finite where a fit runs away


def _cross(a, b) -> tuple[float, float, float]:
    """a × b of two 3-vectors (plain floats: numpy's cross costs more than the product itself)."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _moved_up(up: np.ndarray, basis: np.ndarray, d1: float, d2: float) -> tuple[tuple, np.ndarray]:
    """``retract_on_sphere(up, (d1, d2), basis)`` and its ``tangent_basis`` [3 x 2], in plain floats (the fit
    evaluates them five times per step; numpy's small-array calls cost more than the arithmetic)."""
    step = [basis[i, 0] * d1 + basis[i, 1] * d2 for i in range(3)]
    angle = math.sqrt(step[0] ** 2 + step[1] ** 2 + step[2] ** 2)
    if angle < 1e-15:
        g = [float(up[0]), float(up[1]), float(up[2])]
    else:
        c, s = math.cos(angle), math.sin(angle) / angle
        g = [c * up[i] + s * step[i] for i in range(3)]
    n = math.sqrt(g[0] ** 2 + g[1] ** 2 + g[2] ** 2)
    g = [v / n for v in g]
    norm = math.hypot(g[0], g[1])
    if norm < 1e-12:  # looking straight up or down
        return tuple(g), np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])
    hx, hy = g[0] / norm, g[1] / norm
    return tuple(g), np.array([[-hx * g[2], hy], [-hy * g[2], -hx], [norm, 0.0]])


@dataclass(frozen=True)
class ManhattanFocal:
    """The focal length (pixels) a Manhattan frame of segments gives, its relative 1-sigma, and the number
    of segments (within twice the loss scale) along each of its directions (horizontal, horizontal,
    vertical)."""

    focal_px: float
    sigma_rel: float
    families: tuple[int, int, int]


class _Frame:
    """Residuals of segments against the Manhattan frame of parameters x = (log f, δ1, δ2, yaw).

    A segment's line through its midpoint m and a vanishing point v is l = m × v; its endpoint p lies
    (l·p) / |l₁₂| pixels off it. l·p = v·(p × m), so the numerator is one product with a per-segment vector,
    and l₁₂ = (m_y·v_z − v_y, v_x − m_x·v_z) (m is (m_x, m_y, 1)): all three points' residuals are a few
    products of [N x 3] arrays.
    """

    def __init__(self, segments: np.ndarray, centre: tuple[float, float], up: np.ndarray, loss_scale: float):
        p1, p2 = segments[:, :2], segments[:, 2:]
        self.length = np.linalg.norm(p2 - p1, axis=1)
        ones = np.ones((len(segments), 1))
        end = np.concatenate([p1, ones], axis=1)
        self.mid = 0.5 * (p1 + p2)
        self.across = np.cross(end, np.concatenate([self.mid, ones], axis=1))  # p × m: l·p = v·(p × m)
        self.centre = centre
        self.up = np.asarray(up, dtype=float) / np.linalg.norm(up)
        self.basis = tangent_basis(self.up)
        self.scale = loss_scale

    @staticmethod
    def focal(x: np.ndarray) -> float:
        return math.exp(min(max(float(x[0]), _LOG_F_RANGE[0]), _LOG_F_RANGE[1]))

    def directions(self, x: np.ndarray, yaw_derivative: bool = False) -> np.ndarray:
        """The frame's three directions [3 x 3] (rows: horizontal, horizontal, up), camera coordinates; with
        ``yaw_derivative``, their derivatives in the yaw instead."""
        up, e = _moved_up(self.up, self.basis, float(x[1]), float(x[2]))
        c, s = math.cos(x[3]), math.sin(x[3])
        if yaw_derivative:
            c, s = -s, c
            a = c * e[:, 0] + s * e[:, 1]
            return np.array([a, _cross(up, a), (0.0, 0.0, 0.0)])
        a = c * e[:, 0] + s * e[:, 1]
        return np.array([a, _cross(up, a), up])

    def points(self, x: np.ndarray, d: np.ndarray | None = None, focal_only: bool = False) -> np.ndarray:
        """[3 x 3]: the frame's vanishing points K·d (rows, homogeneous image coordinates), of the directions
        ``d`` (default: the frame's); ``focal_only``: K's focal part alone (f·d_x, f·d_y, 0)."""
        f, (cx, cy) = self.focal(x), self.centre
        d = self.directions(x) if d is None else d
        if focal_only:
            return d @ np.array([[f, 0.0, 0.0], [0.0, f, 0.0], [0.0, 0.0, 0.0]])
        return d @ np.array([[f, 0.0, 0.0], [0.0, f, 0.0], [cx, cy, 1.0]])  # rows K·d

    def _parts(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(l·p, l₁, l₂), each [N x 3]: per segment, against each vanishing point (rows of ``points``)."""
        signed = self.across @ points.T
        l1 = self.mid[:, 1:2] * points[:, 2] - points[:, 1]
        l2 = points[:, 0] - self.mid[:, 0:1] * points[:, 2]
        return signed, l1, l2

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """[N x 3]: each segment's endpoint distance (pixels) from the line joining its midpoint to each of
        the three vanishing points (homogeneous, so a point at infinity is a direction)."""
        signed, l1, l2 = self._parts(self.points(x))
        return np.abs(signed) / np.maximum(np.hypot(l1, l2), 1e-12)

    def cost(self, x: np.ndarray) -> float:
        r = self.residuals(x).min(axis=1)
        return float(np.sum(self.length * np.log1p((r / self.scale) ** 2)))

    def start_costs(self, focals: np.ndarray, yaws: np.ndarray) -> np.ndarray:
        """:meth:`cost` of every start (log f, 0, 0, yaw) of the grid ``focals`` × ``yaws`` at once, [F x Y]:
        the up direction is the fields' at every start, so the frames differ by their yaw and focal only."""
        e = self.basis
        c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
        a = c * e[:, 0] + s * e[:, 1]  # [Y x 3]
        d = np.stack([a, np.cross(self.up, a), np.broadcast_to(self.up, a.shape)], axis=1)  # [Y x 3 x 3]
        f = np.exp(np.clip(focals, *_LOG_F_RANGE))[:, None, None]
        (cx, cy), z = self.centre, d[None, :, :, 2]
        # [F x Y x 3 (points) x 3 (coordinates)], as points() gives them
        points = np.stack(
            np.broadcast_arrays(f * d[None, :, :, 0] + cx * z, f * d[None, :, :, 1] + cy * z, z), -1
        )
        signed = np.einsum("nc,fypc->fynp", self.across, points)
        l1 = self.mid[:, 1, None] * points[:, :, None, :, 2] - points[:, :, None, :, 1]
        l2 = points[:, :, None, :, 0] - self.mid[:, 0, None] * points[:, :, None, :, 2]
        r = (np.abs(signed) / np.maximum(np.hypot(l1, l2), 1e-12)).min(axis=-1)
        return np.sum(self.length * np.log1p((r / self.scale) ** 2), axis=-1)

    def normal_equations(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(H, g, residuals, assignment) of the reweighted problem, each segment on its nearest direction.

        The Jacobian chains each residual's gradient with respect to its vanishing point v,
        ∂r/∂v = sign(l·p)·(p × m)/n − |l·p|·(l₁·(0, −1, m_y) + l₂·(1, 0, −m_x))/n³ with n = |l₁₂|, with the
        vanishing points' derivatives in the four parameters (central differences of three points)."""
        points = self.points(x)
        signed, l1, l2 = self._parts(points)
        norm = np.maximum(np.hypot(l1, l2), 1e-12)
        R = np.abs(signed) / norm
        k = np.argmin(R, axis=1)
        rows = np.arange(len(k))
        r, s, a, b, n = R[rows, k], signed[rows, k], l1[rows, k], l2[rows, k], norm[rows, k]
        w = self.length / (1.0 + (r / self.scale) ** 2) / self.scale**2
        dpoints = np.empty((4, 3, 3))  # [parameter, direction, coordinate]
        dpoints[0] = self.points(x, focal_only=True)  # ∂/∂ log f
        for j in (1, 2):  # the up direction's tangent angles: central differences
            h = np.zeros(4)
            h[j] = 1e-6
            dpoints[j] = (self.points(x + h) - self.points(x - h)) / 2e-6
        dpoints[3] = self.points(x, self.directions(x, yaw_derivative=True))  # K is linear in d
        t = np.abs(s) / n**3
        grad = (np.sign(s) / n)[:, None] * self.across  # ∂r/∂v, [N x 3]
        grad[:, 0] -= t * b
        grad[:, 1] += t * a
        grad[:, 2] -= t * (a * self.mid[:, 1] - b * self.mid[:, 0])
        J = np.einsum("nc,jnc->nj", grad, dpoints[:, k, :])
        return J.T @ (w[:, None] * J), J.T @ (w * r), r, k


def manhattan_focal(
    segments: np.ndarray,
    image_size: tuple[int, int],
    gravity_up: np.ndarray,
    focal_px: float,
    *,
    detector_px: float = 1.0,
    conf: dict | None = None,
) -> ManhattanFocal | None:
    """The focal length of a Manhattan frame fitted to ``segments`` [N x 4] (pinhole image pixels, the
    principal point at the image centre), started from a camera's ``gravity_up`` and ``focal_px``; None
    with too few segments or a fit that says nothing of f.

    ``detector_px``: the size of the detector's pixel in image pixels (the loss scale is in the former).
    """
    conf = resolve(default_conf, conf)
    width, height = image_size
    segments = np.asarray(segments, dtype=float).reshape(-1, 4)
    length = np.linalg.norm(segments[:, 2:] - segments[:, :2], axis=1)
    segments = segments[length > conf["min_length_rel"] * math.hypot(width, height)]
    if len(segments) < conf["min_segments"] or not (np.isfinite(focal_px) and focal_px > 0):
        return None
    centre = principal_point(width, height)
    frame = _Frame(segments, centre, gravity_up, conf["loss_scale_px"] * detector_px)
    focals = np.log(focal_px * np.asarray(conf["focal_starts"], dtype=float))
    yaws = np.radians(np.arange(0.0, 90.0, conf["yaw_step_deg"]))
    best = np.unravel_index(np.argmin(frame.start_costs(focals, yaws)), (len(focals), len(yaws)))
    start = np.array([focals[best[0]], 0.0, 0.0, yaws[best[1]]])
    settings = Settings(
        max_iterations=conf["iterations"], lambda_init=1e-3, lambda_max=1e6, relative_tolerance=0.0,
        step_tolerance=1e-7,
    )  # fmt: skip
    x = levenberg_marquardt(start, frame.cost, lambda x: frame.normal_equations(x)[:2], np.add, settings).x
    if not _LOG_F_RANGE[0] < x[0] < _LOG_F_RANGE[1]:
        return None
    H, _, r, k = frame.normal_equations(x)
    variance = float(covariance(H)[0, 0])
    if not (np.isfinite(variance) and variance >= 0):
        return None
    inlier = r < 2.0 * frame.scale
    families = tuple(int(np.sum(inlier & (k == j))) for j in range(3))
    sigma = max(conf["sigma_scale"] * math.sqrt(variance), conf["sigma_floor"])
    return ManhattanFocal(frame.focal(x), sigma, families)  # type: ignore[arg-type]


def stable_manhattan_focal(
    segments: np.ndarray,
    coarse_segments: np.ndarray,
    image_size: tuple[int, int],
    gravity_up: np.ndarray,
    focal_px: float,
    *,
    detector_px: tuple[float, float] = (1.0, 1.0),
    conf: dict | None = None,
) -> ManhattanFocal | None:
    """:func:`manhattan_focal` of ``segments``, with the distance in log f from the frame fitted to
    ``coarse_segments`` (the same image's, found at ``stability_scale`` of the resolution) added to its
    sigma in quadrature; None where either fit gives none (a frame the coarser edges do not show is not
    the scene's). ``detector_px``: the two detectors' pixel sizes, in image pixels."""
    found = manhattan_focal(
        segments, image_size, gravity_up, focal_px, detector_px=detector_px[0], conf=conf
    )  # fmt: skip
    if found is None:
        return None
    coarse = manhattan_focal(
        coarse_segments, image_size, gravity_up, focal_px, detector_px=detector_px[1], conf=conf
    )  # fmt: skip
    if coarse is None:
        return None
    moved = abs(math.log(found.focal_px / coarse.focal_px))
    return ManhattanFocal(found.focal_px, math.hypot(found.sigma_rel, moved), found.families)
