"""Local-feature matches between the two views: OpenCV SIFT, Lowe's ratio test and a mutual check."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

default_conf = {
    "max_side": 1200,  # images are shrunk so their long side is at most this before detection
    "max_features": 4000,  # SIFT keypoints per image
    "ratio": 0.75,  # Lowe's ratio test
    "mutual": True,  # keep a match only if it is also the best match from right to left
}


@dataclass
class Matches:
    """Matched pixel coordinates [N x 2] in each original (not shrunk) image, OpenCV pixel centres."""

    left: np.ndarray
    right: np.ndarray

    def __len__(self) -> int:
        return len(self.left)


def _grey_and_scale(image: np.ndarray, max_side: int) -> tuple[np.ndarray, float]:
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    scale = min(1.0, max_side / max(grey.shape[:2]))
    if scale < 1.0:
        size = (round(grey.shape[1] * scale), round(grey.shape[0] * scale))
        grey = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
    return grey, scale


def match_features(left: np.ndarray, right: np.ndarray, conf: dict | None = None) -> Matches:
    """SIFT matches between two images (H x W x 3 uint8 RGB, or grey), in original pixel coordinates."""
    conf = {**default_conf, **(conf or {})}
    sift = cv2.SIFT_create(nfeatures=conf["max_features"])
    keypoints, descriptors, scales = [], [], []
    for image in (left, right):
        grey, scale = _grey_and_scale(image, conf["max_side"])
        kp, desc = sift.detectAndCompute(grey, None)
        keypoints.append(kp)
        descriptors.append(desc)
        scales.append(scale)
    empty = Matches(np.zeros((0, 2)), np.zeros((0, 2)))
    if descriptors[0] is None or descriptors[1] is None or len(keypoints[0]) < 2 or len(keypoints[1]) < 2:
        return empty
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    forward = matcher.knnMatch(descriptors[0], descriptors[1], k=2)
    pairs = [
        (m.queryIdx, m.trainIdx)
        for m, n in (p for p in forward if len(p) == 2)
        if m.distance < conf["ratio"] * n.distance
    ]
    if conf["mutual"] and pairs:
        backward = matcher.match(descriptors[1], descriptors[0])
        best_back = {m.queryIdx: m.trainIdx for m in backward}
        pairs = [(i, j) for i, j in pairs if best_back.get(j) == i]
    if not pairs:
        return empty
    idx = np.array(pairs)
    pts = []
    for side, scale in enumerate(scales):
        xy = np.array([keypoints[side][k].pt for k in idx[:, side]], dtype=float)
        pts.append((xy + 0.5) / scale - 0.5)  # pixel-centre-correct undo of the shrink
    return Matches(pts[0], pts[1])
