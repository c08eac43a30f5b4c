"""Pinhole camera with fx = fy = f and the principal point at (w/2, h/2), and the network's resize/crop.

Pixel (0, 0) is the centre of the top-left pixel (OpenCV). Focal lengths are in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def focal_from_vfov(vfov: np.ndarray | float, height: float) -> np.ndarray:
    """Focal length in pixels from the vertical field of view in radians."""
    return np.asarray(height / (2.0 * np.tan(np.asarray(vfov, dtype=float) / 2.0)))


def vfov_from_focal(focal: np.ndarray | float, height: float) -> np.ndarray:
    """Vertical field of view in radians, ``2·atan(h / (2·f))``."""
    return np.asarray(2.0 * np.arctan(height / (2.0 * np.asarray(focal, dtype=float))))


def principal_point(width: float, height: float) -> tuple[float, float]:
    """The principal point convention of the project: (w/2, h/2)."""
    return width / 2.0, height / 2.0


def intrinsic_matrix(focal: float, width: float, height: float) -> np.ndarray:
    """K [3 x 3] with fx = fy = focal and the principal point at (w/2, h/2)."""
    cx, cy = principal_point(width, height)
    return np.array([[focal, 0.0, cx], [0.0, focal, cy], [0.0, 0.0, 1.0]])


TURNS_DEG = (0, 90, 180, 270)


@dataclass(frozen=True)
class ImageTurn:
    """Images turned clockwise by ``degrees`` (0, 90, 180 or 270) before they are read, for cameras mounted
    upside down or on their side: the network knows views rolled by at most 45°.

    A turned image is the image of a virtual camera rolled about its optical axis (``rotation``), and what is
    found in it is turned back exactly: points with :meth:`points_back`, camera-frame vectors with
    ``rotation.T``. The principal point stays the project's (w/2, h/2) of each image, one pixel from where
    the turn carries the other one's: far below what one pair can tell of it.
    """

    degrees: int = 0

    def __post_init__(self) -> None:
        if self.degrees not in TURNS_DEG:
            raise ValueError(f"a turn is 0, 90, 180 or 270 degrees, got {self.degrees}")

    @property
    def quarters(self) -> int:
        return self.degrees // 90

    @property
    def rotation(self) -> np.ndarray:
        """[3 x 3] with ``X_turned = rotation @ X`` in camera coordinates (x right, y down, z forward)."""
        quarter = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        return np.linalg.matrix_power(quarter, self.quarters)

    def image(self, image: np.ndarray) -> np.ndarray:
        """The image turned (the same array for 0°)."""
        return image if self.quarters == 0 else np.ascontiguousarray(np.rot90(image, -self.quarters))

    def size_back(self, size: tuple[int, int]) -> tuple[int, int]:
        """The original (width, height) of a turned image's size."""
        return (size[1], size[0]) if self.quarters % 2 else (size[0], size[1])

    def points_back(self, points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """Pixels [... x 2] of a turned image → the original image's, of ``size`` (width, height)."""
        p = np.asarray(points, dtype=float)
        x, y = p[..., 0], p[..., 1]
        w, h = size
        back = {0: (x, y), 1: (y, h - 1 - x), 2: (w - 1 - x, h - 1 - y), 3: (w - 1 - y, x)}[self.quarters]
        return np.stack(back, axis=-1)


@dataclass(frozen=True)
class ResizeCrop:
    """An image resized by ``scale`` then cropped to ``out_size`` starting at ``crop`` (resized pixels).

    Maps pixel centres exactly: ``x_out = (x_in + 0.5)·scale - 0.5 - crop_x``.
    """

    in_size: tuple[int, int]  # (width, height) of the original image
    scale: float
    resized_size: tuple[int, int]  # (width, height) after resizing, before cropping
    crop: tuple[int, int]  # (x, y) of the crop's top-left pixel in the resized image
    out_size: tuple[int, int]  # (width, height) given to the network

    def points_to_output(self, points: np.ndarray) -> np.ndarray:
        """Original pixel coordinates [... x 2] → network-input pixel coordinates."""
        return (np.asarray(points, dtype=float) + 0.5) * self.scale - 0.5 - np.asarray(self.crop, dtype=float)

    def points_to_input(self, points: np.ndarray) -> np.ndarray:
        """Network-input pixel coordinates [... x 2] → original pixel coordinates."""
        return (np.asarray(points, dtype=float) + 0.5 + np.asarray(self.crop, dtype=float)) / self.scale - 0.5

    def focal_to_input(self, focal: float) -> float:
        """A focal length fitted on the network input, in original pixels."""
        return float(focal) / self.scale

    def focal_to_output(self, focal: float) -> float:
        """A focal length in original pixels, on the network input."""
        return float(focal) * self.scale


def resize_crop_for_network(width: int, height: int, short_side: int = 320, multiple: int = 32) -> ResizeCrop:
    """Resize so the short side is ``short_side``, then centre-crop both sides to a multiple of ``multiple``.

    The crop is centred to within half a resized pixel, so the principal point (w/2, h/2) of the original
    stays at the centre of the network input (the gravity direction is unchanged by resizing and cropping).
    """
    if width < 1 or height < 1:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    if short_side < multiple:
        raise ValueError(f"the short side ({short_side}) must be at least the multiple ({multiple})")
    scale = short_side / min(width, height)
    rw, rh = round(width * scale), round(height * scale)  # both ≥ short_side ≥ multiple
    ow, oh = rw // multiple * multiple, rh // multiple * multiple
    crop = ((rw - ow) // 2, (rh - oh) // 2)
    return ResizeCrop((width, height), scale, (rw, rh), crop, (ow, oh))


def apply_resize_crop(image: np.ndarray, rc: ResizeCrop) -> np.ndarray:
    """Resize (area filter when shrinking, linear when enlarging) and crop an image [H x W (x C)]."""
    import cv2

    h, w = image.shape[:2]
    if (w, h) != rc.in_size:
        raise ValueError(f"image is {w}x{h}, the resize/crop was planned for {rc.in_size[0]}x{rc.in_size[1]}")
    interp = cv2.INTER_AREA if rc.scale < 1 else cv2.INTER_LINEAR
    resized = cv2.resize(image, rc.resized_size, interpolation=interp) if rc.scale != 1 else image
    x, y = rc.crop
    return resized[y : y + rc.out_size[1], x : x + rc.out_size[0]]


# ------------------------------------------------------------------------------------ radial lens distortion
# Fitted from the matches (fuse/pose.py) with the one-parameter division model, undistorted = distorted /
# (1 + k·r_d²) in normalised coordinates, which inverts in closed form; written to files as OpenCV's
# polynomial model (k1, k2, k3), which every reader understands.


def corner_radius(K: np.ndarray) -> float:
    """The image's largest normalised radius, corner distance / focal (principal point at the centre)."""
    return float(np.hypot(K[0, 2], K[1, 2]) / K[0, 0])


def undistort_division(points: np.ndarray, K: np.ndarray, k: float) -> np.ndarray:
    """Pixels [N x 2] seen through a division-model lens with parameter ``k`` → pinhole pixels of K."""
    points = np.asarray(points, dtype=float)
    if k == 0.0 or len(points) == 0:
        return points
    f = np.array([K[0, 0], K[1, 1]])
    c = np.array([K[0, 2], K[1, 2]])
    x = (points - c) / f
    return x / (1.0 + k * np.sum(x * x, axis=-1, keepdims=True)) * f + c


def division_limit(max_radius: float) -> float:
    """The most negative (barrel) ``k`` the division model takes out to ``max_radius`` (normalised).

    Beyond it 1 + k·r² falls below 0.1 and the model folds over; strong fisheyes need another model.
    """
    return -0.9 / max(float(max_radius) ** 2, 1e-12)


def opencv_from_division(k: float, max_radius: float, samples: int = 64) -> np.ndarray:
    """OpenCV distortion ``[k1, k2, 0, 0, k3]`` closest to the division model ``k`` out to ``max_radius``.

    ``max_radius`` is the largest normalised radius in the image (corner distance / focal). The fit is
    least squares on r_d/r_u - 1 = k1·r_u² + k2·r_u⁴ + k3·r_u⁶ over radii evenly spaced in the distorted
    image. No distortion (k = 0) gives an empty array, OpenCV's and the dataset layout's "none".
    """
    if k == 0.0:
        return np.zeros(0)
    r_d = np.linspace(max_radius / samples, max_radius, samples)
    r_u = r_d / (1.0 + k * r_d**2)
    A = np.column_stack([r_u**2, r_u**4, r_u**6])
    k1, k2, k3 = np.linalg.lstsq(A, r_d / r_u - 1.0, rcond=None)[0]
    return np.array([k1, k2, 0.0, 0.0, k3])


def fold_k3(D: np.ndarray, K: np.ndarray, samples: int = 64) -> np.ndarray:
    """OpenCV ``[k1, k2, p1, p2, k3]`` → ``[k1', k2', p1, p2]`` closest over the image (for 4-term formats).

    The radial factor 1 + k1·r² + k2·r⁴ + k3·r⁶ is refitted without r⁶ in least squares over undistorted
    radii out to the image corner's.
    """
    D = np.asarray(D, dtype=float)
    if D.size < 5 or D[4] == 0.0:
        return D[:4].copy()
    k1, k2, k3 = D[0], D[1], D[4]
    r_d = corner_radius(K)
    r_u = r_d
    for _ in range(20):  # fixed point of r_d = r_u·(1 + k1·r_u² + k2·r_u⁴ + k3·r_u⁶)
        r_u = r_d / (1.0 + k1 * r_u**2 + k2 * r_u**4 + k3 * r_u**6)
    r = np.linspace(r_u / samples, r_u, samples)
    A = np.column_stack([r**2, r**4])
    k1_new, k2_new = np.linalg.lstsq(A, k1 * r**2 + k2 * r**4 + k3 * r**6, rcond=None)[0]
    return np.array([k1_new, k2_new, D[2], D[3]])
