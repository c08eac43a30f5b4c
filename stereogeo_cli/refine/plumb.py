"""A lens's radial distortion from the straight edges of one image (plumb lines).

A straight edge in the world is a straight line in a pinhole image; a lens bends it, more the further it
runs from the centre. The line segment detector (``refine/lines.py``) cuts a bent edge into short pieces
that each look straight. Pieces that continue one another (ends close, directions alike, one on the other's
line) are linked into chains; a chain that spans a good part of the image is a candidate plumb line. For
each trial distortion the chain's points are undistorted (division model about the image centre,
``geometry.camera.undistort_division``) and fitted with a line; the distortion that makes the chains
straightest wins.

Not every long edge is straight in the world (a cable, a rounded table), so each chain's misfit is clipped
(``clip_px``): a chain that no distortion straightens costs the same everywhere and so does not vote. The
estimate's 1-sigma comes from resampling the chains (a bootstrap); an image with few or disagreeing chains
gets none (``max_sigma``).

The fusion (``fuse/pose.py``) weighs the estimate in its test of whether the matches show a lens at all:
a camera whose matches bend too little to pass it alone gets its lens where the edges agree. The lens's
k itself stays the matches'. The settings below and what they give on real sets: docs/refine.md, "Lens
from straight edges".

The result is a curvature ``kappa`` in pixels⁻² of the image: undistorted = c + (p − c) / (1 + kappa·r²),
r = |p − c|, so the division model's k in the normalised coordinates of a focal length f is kappa·f².
It does not depend on the focal length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stereogeo_cli.settings import resolve

default_conf = {
    "enabled": True,
    # trial distortions, as the stretch kappa·r² at the image's corner (r: half the diagonal); below about
    # -0.9 the division model folds over, the fusion allows barrel only
    "stretch_range": (-0.6, 0.15),
    "stretch_step": 0.01,
    "min_segment": 0.01,  # shortest segment used, as a share of the image diagonal
    "max_segments": 600,  # the longest this many are linked (linking compares every pair of ends)
    "link_gap": 0.02,  # largest gap between linked ends, share of the diagonal
    "link_angle_deg": 6.0,  # largest angle between linked pieces
    "link_offset": 0.004,  # largest offset of one piece's end from the other's line, share of the diagonal
    "min_span": 0.12,  # shortest chain used, share of the diagonal
    "border_px": 4.0,  # pieces this close to the image border are left out (frames, padding; detector px)
    "clip_px": 0.25,  # a chain's RMS misfit counts up to this (detector pixels at a short side of 480)
    "min_chains": 4,  # fewer chains: no estimate
    "bootstrap": 64,  # resamplings of the chains for the 1-sigma
    # a wider 1-sigma (stretch at the corner): no estimate (too few or disagreeing edges)
    "max_sigma": 0.05,
    # floor of the 1-sigma (stretch at the corner): one k about the image centre is not a real lens
    "min_sigma": 0.03,
}


@dataclass(frozen=True)
class PlumbLens:
    """A radial distortion read from straight edges."""

    kappa: float  # division-model curvature, pixels⁻² (k in normalised coordinates of focal f: kappa·f²)
    sigma_kappa: float  # its 1-sigma
    corner_radius_px: float  # half the image diagonal: kappa·r² there is the stretch at the corner
    chains: int  # chains used

    @property
    def stretch(self) -> float:
        """kappa·r² at the corner: the undistorted corner lies 1/(1 + stretch) as far from the centre."""
        return self.kappa * self.corner_radius_px**2

    def division_k(self, focal_px: float) -> tuple[float, float]:
        """(k, 1-sigma of k) in the normalised coordinates of a camera with this focal length."""
        return self.kappa * focal_px**2, self.sigma_kappa * focal_px**2


def link_chains(segments: np.ndarray, diagonal: float, conf: dict) -> list[np.ndarray]:
    """Chains of segments [N x 4] that continue one another: lists of segment indices (two or more).

    Candidate links join an end of one segment to an end of another: within ``link_gap``, at most
    ``link_angle_deg`` apart in direction, each end within ``link_offset`` of the other segment's line.
    They are taken shortest first, each end at most once and never closing a loop.
    """
    n = len(segments)
    if n < 2:
        return []
    ends = np.concatenate([segments[:, :2], segments[:, 2:]])  # end e belongs to segment e % n
    along = segments[:, 2:] - segments[:, :2]
    unit = along / np.maximum(np.linalg.norm(along, axis=1, keepdims=True), 1e-12)
    normal = np.stack([-unit[:, 1], unit[:, 0]], axis=1)
    reach = conf["link_gap"] * diagonal
    # pairs of ends within reach in x (sorted by x: each end and the ends after it up to x + reach)
    order = np.argsort(ends[:, 0], kind="stable")
    xs = ends[order, 0]
    span = np.searchsorted(xs, xs + reach, side="left") - np.arange(len(xs)) - 1
    first = np.repeat(np.arange(len(xs)), span)
    second = first + 1 + np.arange(len(first)) - np.repeat(np.cumsum(span) - span, span)
    a, b = order[first], order[second]
    gap = np.hypot(*(ends[a] - ends[b]).T)
    near = gap < reach
    a, b, gap = a[near], b[near], gap[near]
    i, j = a % n, b % n
    other = i != j
    a, b, i, j, gap = a[other], b[other], i[other], j[other], gap[other]
    parallel = np.abs(np.sum(unit[i] * unit[j], axis=1)) >= np.cos(np.radians(conf["link_angle_deg"]))
    offset = ends[b] - ends[a]
    lateral = np.maximum(
        np.abs(np.sum(offset * normal[i], axis=1)), np.abs(np.sum(offset * normal[j], axis=1))
    )
    keep = parallel & (lateral <= conf["link_offset"] * diagonal)
    a, b, i, j, gap = a[keep], b[keep], i[keep], j[keep], gap[keep]
    parent = list(range(n))

    def root(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    used: set[int] = set()
    for k in np.argsort(gap, kind="stable"):
        if a[k] in used or b[k] in used or root(i[k]) == root(j[k]):
            continue
        used.update((int(a[k]), int(b[k])))
        parent[root(i[k])] = root(j[k])
    groups: dict[int, list[int]] = {}
    for s in range(n):
        groups.setdefault(root(s), []).append(s)
    return [np.array(g) for g in groups.values() if len(g) >= 2]


def _chain_points(segments: np.ndarray, members: np.ndarray, step: float) -> np.ndarray:
    """Points every ``step`` pixels or so along each member segment, both ends included."""
    start, end = segments[members, :2], segments[members, 2:]
    count = np.maximum(2, (np.hypot(*(end - start).T) / step).astype(int) + 1)
    owner = np.repeat(np.arange(len(members)), count)
    fraction = (np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)) / (count[owner] - 1)
    return start[owner] + fraction[:, None] * (end - start)[owner]


def _long_edges(segments, size, center, detector_scale, conf) -> list[np.ndarray]:
    """The image's long edges: the longest segments away from the border, linked into chains that span
    ``min_span`` of the diagonal or more; each chain's points relative to the distortion ``center``."""
    width, height = size
    diagonal = float(np.hypot(width, height))
    segments = np.asarray(segments, dtype=float).reshape(-1, 4)
    length = np.linalg.norm(segments[:, 2:] - segments[:, :2], axis=1)
    margin = conf["border_px"] * detector_scale
    xs, ys = segments[:, [0, 2]], segments[:, [1, 3]]
    inside = (np.minimum(xs, width - 1 - xs).min(axis=1) > margin) & (
        np.minimum(ys, height - 1 - ys).min(axis=1) > margin
    )
    keep = np.flatnonzero((length >= conf["min_segment"] * diagonal) & inside)
    keep = keep[np.argsort(-length[keep], kind="stable")[: conf["max_segments"]]]
    segments = segments[keep]
    chains = []
    for members in link_chains(segments, diagonal, conf):
        points = _chain_points(segments, members, 0.005 * diagonal)
        centred = points - points.mean(axis=0)
        direction = np.linalg.svd(centred, full_matrices=False)[2][0]
        if np.ptp(centred @ direction) >= conf["min_span"] * diagonal:
            chains.append(points - np.asarray(center, dtype=float))
    return chains


def plumb_line_distortion(
    segments: np.ndarray,
    size: tuple[int, int],
    center: tuple[float, float],
    detector_scale: float = 1.0,
    conf: dict | None = None,
    rng: np.random.Generator | None = None,
) -> PlumbLens | None:
    """The radial distortion that straightens the image's long edges, or None where too few are found.

    Args:
        segments: line segments [N x 4] (x1, y1, x2, y2) in image pixels (``refine.lines.detect_segments``).
        size: the image's (width, height).
        center: the distortion centre in pixels (the principal point).
        detector_scale: image pixels per detector pixel (the detector may run on a reduced copy); the
            border margin and the misfit clip are in detector pixels.
    """
    conf = resolve(default_conf, conf)
    corner = 0.5 * float(np.hypot(*size))
    chains = _long_edges(segments, size, center, detector_scale, conf)
    if len(chains) < conf["min_chains"]:
        return None
    low, high = conf["stretch_range"]
    stretch = np.arange(low, high + 0.5 * conf["stretch_step"], conf["stretch_step"])
    kappa = stretch / corner**2
    clip = conf["clip_px"] * detector_scale
    # every chain's points undistorted at every trial at once: per trial and chain, the second moments
    # give the misfit of the best line (its smallest principal variance)
    points = np.concatenate(chains)
    counts = np.array([len(c) for c in chains])
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    r2 = np.sum(points * points, axis=1)
    undistorted = points[None] / (1.0 + kappa[:, None, None] * r2[None, :, None])  # trial x point x 2
    x, y = undistorted[..., 0], undistorted[..., 1]

    def mean(values: np.ndarray) -> np.ndarray:
        return np.add.reduceat(values, starts, axis=1) / counts

    mx, my = mean(x), mean(y)
    a, b, c = mean(x * x) - mx * mx, mean(y * y) - my * my, mean(x * y) - mx * my
    smallest = np.maximum(0.5 * (a + b) - np.sqrt(0.25 * (a - b) ** 2 + c * c), 0.0)
    cost = np.minimum(smallest, clip**2) * counts  # trial x chain: clipped mean square misfit x points

    def best(weights: np.ndarray) -> float:
        total = cost @ weights
        m = int(np.argmin(total))
        if 0 < m < len(total) - 1:  # parabola through the minimum and its neighbours
            curvature = total[m - 1] - 2 * total[m] + total[m + 1]
            if curvature > 0:
                return float(
                    stretch[m] + 0.5 * conf["stretch_step"] * (total[m - 1] - total[m + 1]) / curvature
                )
        return float(stretch[m])

    estimate = best(np.ones(len(chains)))
    if not low < estimate < high:  # the edges want more than the range allows: not a lens this model takes
        return None
    rng = rng if rng is not None else np.random.default_rng(0)
    draws = [best(rng.multinomial(len(chains), np.full(len(chains), 1.0 / len(chains))).astype(float))
             for _ in range(conf["bootstrap"])]  # fmt: skip
    sigma = max(float(np.std(draws)), conf["min_sigma"])
    if sigma > conf["max_sigma"]:
        return None
    return PlumbLens(estimate / corner**2, sigma / corner**2, corner, len(chains))
