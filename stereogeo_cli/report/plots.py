"""The report's plots (matplotlib, its Agg canvas; imported only here, when a report is written): the
matches' row errors, the focal length's evidence, a sequence's trajectory, frames and blocks, and a rig's
pairs against the joint calibration. Each returns PNG bytes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from stereogeo_cli.report.inputs import FocalRead

DPI = 100
RESULT = "#c0392b"  # the calibration's own value, in every plot
READ = "#2c6fbb"
SIDES = ("left", "right")
SIDE_COLOURS = {"left": "#2c6fbb", "right": "#e67e22"}


def _figure(width_in: float, height_in: float, rows: int = 1, cols: int = 1, **grid):
    """A figure on matplotlib's Agg canvas (no pyplot: no global state, no GUI backend) and its axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(width_in, height_in), dpi=DPI)
    FigureCanvasAgg(figure)
    axes = figure.subplots(rows, cols, squeeze=False, **grid)
    for ax in axes.ravel():
        ax.grid(True, color="#dddddd", linewidth=0.6)
        ax.set_axisbelow(True)
        ax.tick_params(labelsize=8)
    return figure, axes


def _png(figure) -> bytes:
    figure.canvas.draw()
    rgba = np.asarray(figure.canvas.buffer_rgba())
    ok, data = cv2.imencode(".png", cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise RuntimeError("PNG encoding of a report plot failed")
    return data.tobytes()


def _point(ax, x: float, y: float, sigma: float | None, colour: str, marker: str, across: bool = True):
    """A point with its 1-sigma bar (horizontal where ``across``); no bar where there is no sigma."""
    if sigma is not None and math.isfinite(sigma) and sigma > 0:
        ax.hlines(y, x - sigma, x + sigma, color=colour, linewidth=1.4)
        ax.plot([x - sigma, x + sigma], [y, y], "|", color=colour, markersize=7)
    ax.plot([x], [y], marker, color=colour, markersize=5)


def row_error_plot(errors: np.ndarray) -> bytes:
    """The histogram of the matches' row differences after rectification (px), their median and 95th
    percentile, and ROS's marks of a good (0.25 px) and an excellent (0.1 px) stereo calibration."""
    errors = np.abs(np.asarray(errors, float))
    median, p95 = float(np.median(errors)), float(np.percentile(errors, 95))
    top = max(float(np.percentile(errors, 99)) * 1.1, 0.3)
    figure, axes = _figure(6.4, 2.4)
    ax = axes[0, 0]
    counts, edges = np.histogram(np.clip(errors, 0, top), bins=40, range=(0, top))
    ax.stairs(counts, edges, fill=True, color=READ, alpha=0.85)
    for x, style, label in ((median, "-", f"median {median:.2f} px"), (p95, "--", f"95 % {p95:.2f} px")):
        ax.axvline(x, color=RESULT, linestyle=style, linewidth=1.6, label=label)
    for x in (0.1, 0.25):
        ax.axvline(x, color="#555555", linestyle=":", linewidth=1.0)
    ax.set_xlim(0, top)
    ax.set_xlabel("row difference of a match after rectification (px)", fontsize=9)
    ax.set_ylabel("matches", fontsize=9)
    ax.legend(fontsize=8, loc="upper right")
    figure.subplots_adjust(left=0.09, right=0.98, bottom=0.2, top=0.95)
    return _png(figure)


def focal_plot(reads: Sequence[Sequence[FocalRead]], results: Sequence[tuple[float, float | None]]) -> bytes:
    """Per camera (a panel each) its focal length's pieces of evidence as points with their 1-sigma bars,
    and the calibration's focal length and 1-sigma (red point, shaded band) that combines them."""
    rows = max(len(r) for r in reads) + 1
    figure, axes = _figure(6.4, 0.45 * rows + 0.9, 1, 2)
    for ax, side, side_reads, (focal, sigma) in zip(axes[0], SIDES, reads, results, strict=True):
        labels = [r.label for r in side_reads] + ["result"]
        ys = np.arange(len(labels))[::-1]
        for y, read in zip(ys[:-1], side_reads, strict=True):
            _point(ax, read.focal_px, y, read.sigma_px, READ, "o")
        if sigma:
            ax.axvspan(focal - sigma, focal + sigma, color=RESULT, alpha=0.12, linewidth=0)
        _point(ax, focal, ys[-1], sigma, RESULT, "D")
        ax.axvline(focal, color=RESULT, linewidth=0.8, alpha=0.6)
        ax.set_yticks(ys, labels, fontsize=8)
        ax.set_ylim(-0.7, len(labels) - 0.3)
        ax.set_title(f"{side} camera: focal length (px)", fontsize=9)
    figure.subplots_adjust(left=0.22, right=0.98, bottom=0.5 / (0.45 * rows + 0.9), top=0.86, wspace=0.75)
    return _png(figure)


def trajectory_plot(positions: np.ndarray, axes_dir: np.ndarray) -> bytes:
    """The left camera's path seen from above (world x, y; z up), in time from dark to light, with its
    viewing direction every few frames, the start (circle) and the end (square)."""
    positions = np.asarray(positions, float)
    figure, axes = _figure(4.6, 4.0)
    ax = axes[0, 0]
    order = np.arange(len(positions))
    ax.plot(positions[:, 0], positions[:, 1], color="#999999", linewidth=0.8)
    points = ax.scatter(positions[:, 0], positions[:, 1], c=order, cmap="viridis", s=14, zorder=3)
    span = float(np.ptp(positions[:, :2], axis=0).max()) if len(positions) > 1 else 1.0
    step = max(1, len(positions) // 12)
    for p, d in zip(positions[::step], np.asarray(axes_dir, float)[::step], strict=True):
        flat = d[:2] / max(float(np.linalg.norm(d[:2])), 1e-9)
        ax.annotate("", p[:2] + 0.08 * max(span, 1e-6) * flat, p[:2],
                    arrowprops={"arrowstyle": "->", "color": RESULT, "lw": 1.0})  # fmt: skip
    ax.plot(*positions[0, :2], "o", color="black", markersize=7, fillstyle="none")
    ax.plot(*positions[-1, :2], "s", color="black", markersize=7, fillstyle="none")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)", fontsize=9)
    ax.set_ylabel("y (m)", fontsize=9)
    colour = figure.colorbar(points, ax=ax, shrink=0.8)
    colour.set_label("frame (registered, in time order)", fontsize=8)
    colour.ax.tick_params(labelsize=7)
    figure.subplots_adjust(left=0.16, right=0.95, bottom=0.12, top=0.97)
    return _png(figure)


def frames_plot(frames: Sequence[dict], reprojection: dict[int, float] | None) -> bytes:
    """Per frame (its index in the sequence) each camera's roll and pitch, and where known the mean
    reprojection error of its two images in the adjusted model."""
    from matplotlib.ticker import MaxNLocator

    panels = 3 if reprojection else 2
    figure, axes = _figure(6.4, 1.5 * panels + 0.4, panels, 1, sharex=True)
    index = np.array([f["index"] for f in frames])
    for ax, key, name in zip(axes[:2, 0], ("roll_deg", "pitch_deg"), ("roll (°)", "pitch (°)"), strict=True):
        for side in SIDES:
            values = [(f.get(side) or {}).get(key) for f in frames]
            ax.plot(index, [math.nan if v is None else v for v in values], ".-", color=SIDE_COLOURS[side],
                    linewidth=1.0, markersize=4, label=side)  # fmt: skip
        ax.set_ylabel(name, fontsize=9)
    axes[0, 0].legend(fontsize=8, ncol=2, loc="best")
    if reprojection:
        ax = axes[2, 0]
        ax.bar(index, [reprojection.get(int(i), math.nan) for i in index], color=READ, width=0.8)
        ax.set_ylabel("reprojection (px)", fontsize=9)
    axes[-1, 0].set_xlabel("frame", fontsize=9)
    axes[-1, 0].xaxis.set_major_locator(MaxNLocator(integer=True))
    figure.subplots_adjust(left=0.12, right=0.98, bottom=0.35 / (1.5 * panels + 0.4) + 0.05, top=0.97)
    return _png(figure)


def blocks_plot(
    block_focals: Sequence[Sequence[float]], results: Sequence[tuple[float, float | None]]
) -> bytes:
    """Each camera's focal length fitted without each stretch of frames in turn, against the calibration's
    (red line, its 1-sigma shaded)."""
    values = np.asarray(block_focals, float)
    figure, axes = _figure(6.4, 2.3, 1, 2)
    blocks = np.arange(1, len(values) + 1)
    for ax, side, column, (focal, sigma) in zip(axes[0], SIDES, values.T, results, strict=True):
        if sigma:
            ax.axhspan(focal - sigma, focal + sigma, color=RESULT, alpha=0.12, linewidth=0)
        ax.axhline(focal, color=RESULT, linewidth=1.2)
        ax.plot(blocks, column, "o", color=SIDE_COLOURS[side], markersize=6)
        ax.set_xticks(blocks)
        ax.set_xlabel("stretch left out", fontsize=9)
        ax.set_title(f"{side} camera: focal length (px)", fontsize=9)
    figure.subplots_adjust(left=0.1, right=0.98, bottom=0.22, top=0.88, wspace=0.3)
    return _png(figure)


def _short(name: str, most: int = 20) -> str:
    """A pair's name as a plot's label: a long one keeps its start and its end."""
    return name if len(name) <= most else f"{name[: most // 2 - 1]}…{name[-(most // 2 - 1) :]}"


def same_rig_plot(
    names: Sequence[str],
    focals: Sequence[Sequence[tuple]],
    joint: Sequence[tuple],
    rotations: Sequence[tuple[float, float | None]],
    joint_sigma_deg: float | None,
) -> bytes:
    """Per pair (a row each) each camera's focal length and how far its R is from the joint R, against the
    joint calibration's (red; its 1-sigma shaded)."""
    ys = np.arange(len(names))[::-1]
    figure, axes = _figure(6.6, 0.32 * len(names) + 1.1, 1, 3, sharey=True)
    titles = ("left focal (px)", "right focal (px)", "R from the joint R (°)")
    for ax, title in zip(axes[0], titles, strict=True):
        ax.set_title(title, fontsize=9)
    for ax, side_focals, (focal, sigma) in zip(axes[0, :2], focals, joint, strict=True):
        if sigma:
            ax.axvspan(focal - sigma, focal + sigma, color=RESULT, alpha=0.12, linewidth=0)
        ax.axvline(focal, color=RESULT, linewidth=1.2)
        for y, (f, s) in zip(ys, side_focals, strict=True):
            _point(ax, f, y, s, READ, "o")
    ax = axes[0, 2]
    if joint_sigma_deg:
        ax.axvspan(0, joint_sigma_deg, color=RESULT, alpha=0.12, linewidth=0)
    ax.axvline(0, color=RESULT, linewidth=1.2)
    for y, (angle, sigma) in zip(ys, rotations, strict=True):
        _point(ax, angle, y, sigma, READ, "o")
    axes[0, 0].set_yticks(ys, [_short(n) for n in names], fontsize=7)
    figure.subplots_adjust(left=0.2, right=0.98, bottom=0.45 / (0.32 * len(names) + 1.1), top=0.88,
                           wspace=0.12)  # fmt: skip
    return _png(figure)
