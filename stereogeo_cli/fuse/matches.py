"""Local-feature matches between the two views: OpenCV SIFT, Lowe's ratio test and a mutual check."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from stereogeo_cli.settings import resolve

default_conf = {
    "max_side": 1200,  # images are shrunk so their long side is at most this before detection
    "max_features": 4000,  # SIFT keypoints per image
    "ratio": 0.75,  # Lowe's ratio test
    "mutual": True,  # keep a match only if it is also the best match from right to left
}


@dataclass
class Matches:
    """Matched pixel coordinates [N x 2] in each original (not shrunk) image, OpenCV pixel centres, and how
    many features each image had to match (0: not counted): textured images that match few of them see
    different parts of the scene."""

    left: np.ndarray
    right: np.ndarray
    features: tuple[int, int] = (0, 0)

    def __len__(self) -> int:
        return len(self.left)


def _grey_and_scale(image: np.ndarray, max_side: int) -> tuple[np.ndarray, float]:
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    scale = min(1.0, max_side / max(grey.shape[:2]))
    if scale < 1.0:
        size = (round(grey.shape[1] * scale), round(grey.shape[0] * scale))
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
    return grey, scale


def mutual_ratio_matches(a: np.ndarray, b: np.ndarray, ratio: float, mutual: bool = True) -> np.ndarray:
    """Index pairs [M x 2] (i in a, j in b) of descriptors [N x D] whose nearest neighbour in b passes Lowe's
    ratio test against the second nearest (L2) and, with ``mutual``, is also a's nearest from b's side.

    One matrix of squared distances serves both directions (what a brute-force matcher's k=2 search one
    way and 1-NN search the other way compute twice).
    """
    a, b = np.asarray(a, dtype=np.float32), np.asarray(b, dtype=np.float32)
    if len(a) < 1 or len(b) < 2:
        return np.zeros((0, 2), dtype=int)
    d2 = np.einsum("ij,ij->i", a, a)[:, None] + np.einsum("ij,ij->i", b, b)[None, :]
    products = a @ b.T
    products *= 2.0
    d2 -= products  # |a|² + |b|² − 2·a·b, in place: the matrix is the largest array of the matching
    del products
    np.maximum(d2, 0.0, out=d2)
    rows = np.arange(len(a))
    best = np.argmin(d2, axis=1)
    d_best = d2[rows, best]
    # (along rows of the transposed copy: numpy's argmin down the columns of a large matrix is several times
    # slower than the copy)
    nearest_in_a = np.argmin(np.ascontiguousarray(d2.T), axis=1) if mutual else None
    # the second nearest: the row's minimum once its nearest is masked (two vectorised passes, a third of
    # the time of a partial sort; where two are equally near, the ratio test fails whichever is taken)
    d2[rows, best] = np.inf
    d_next = d2.min(axis=1)
    keep = np.sqrt(d_best) < ratio * np.sqrt(d_next)
    if mutual:
        keep &= nearest_in_a[best] == rows
    return np.column_stack([np.nonzero(keep)[0], best[keep]])


@dataclass
class Features:
    """One image's SIFT keypoints: their pixel coordinates [N x 2] in the original (not shrunk) image and
    their descriptors [N x 128] (None where the detector found none)."""

    xy: np.ndarray
    descriptors: np.ndarray | None


def detect_features(image: np.ndarray, conf: dict | None = None) -> Features:
    """SIFT keypoints of one image (H x W x 3 uint8 RGB, or grey), in original pixel coordinates. The two
    images of a pair are independent: the pipeline detects them on two threads."""
    conf = resolve(default_conf, conf)
    grey, scale = _grey_and_scale(image, conf["max_side"])
    keypoints, descriptors = cv2.SIFT_create(nfeatures=conf["max_features"]).detectAndCompute(grey, None)
    xy = np.array([kp.pt for kp in keypoints], dtype=float).reshape(-1, 2)
    return Features((xy + 0.5) / scale - 0.5, descriptors)  # pixel-centre-correct undo of the shrink


def match_detected(left: Features, right: Features, conf: dict | None = None) -> Matches:
    """The matches between two images' features (:func:`mutual_ratio_matches` on their descriptors)."""
    conf = resolve(default_conf, conf)
    features = (len(left.xy), len(right.xy))
    empty = Matches(np.zeros((0, 2)), np.zeros((0, 2)), features)
    if left.descriptors is None or right.descriptors is None or len(left.xy) < 2 or len(right.xy) < 2:
        return empty
    idx = mutual_ratio_matches(left.descriptors, right.descriptors, conf["ratio"], conf["mutual"])
    if len(idx) == 0:
        return empty
    return Matches(left.xy[idx[:, 0]], right.xy[idx[:, 1]], features)


def match_features(left: np.ndarray, right: np.ndarray, conf: dict | None = None) -> Matches:
    """SIFT matches between two images (H x W x 3 uint8 RGB, or grey), in original pixel coordinates."""
    return match_detected(detect_features(left, conf), detect_features(right, conf), conf)
