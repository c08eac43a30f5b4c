"""Headless OpenGL on the CPU: an EGL context on Mesa's software rasteriser (llvmpipe), and the projection.

One context per process, created lazily and reused (:func:`get_context`). The projection follows the
project's camera convention exactly: OpenCV axes (x right, y down, z forward), principal point at
(w/2, h/2), pixel (0, 0) the centre of the top-left pixel. Frames are rendered "upside down" in GL's
window coordinates so that GL row 0 is image row 0 and no flip is needed when reading back.

Where Mesa is absent and a GPU driver provides EGL (a GPU training machine), the context is the driver's:
the same scenes and cameras, not the same bytes.
"""

from __future__ import annotations

import os

import numpy as np

from stereogeo_cli.errors import EXIT_INTERNAL, StereoGeoError

_CONTEXT = None
_CONTEXT_PID = None

APT_PACKAGES = ("libegl1", "libegl-mesa0", "libgl1-mesa-dri", "libgl1")


def _configure_environment() -> None:
    # Headless: no X11/Wayland display; force Mesa's software rasteriser even where a GPU driver exists,
    # so renders are identical on every machine.
    os.environ.setdefault("EGL_PLATFORM", "surfaceless")
    os.environ.setdefault("LIBGL_ALWAYS_SOFTWARE", "1")
    os.environ.setdefault("GALLIUM_DRIVER", "llvmpipe")
    os.environ.setdefault("MESA_LOADER_DRIVER_OVERRIDE", "llvmpipe")


def get_context():
    """The process's moderngl context (EGL, llvmpipe), created on first use.

    A context inherited through ``fork`` is unusable and a new one would hang, so that case raises.
    Raises StereoGeoError with the Debian packages to install when EGL cannot start.
    """
    global _CONTEXT, _CONTEXT_PID
    if _CONTEXT is not None and _CONTEXT_PID == os.getpid():
        return _CONTEXT
    if _CONTEXT is not None:  # Mesa's threads do not survive fork: a new context here would hang
        raise StereoGeoError(
            "this process was forked from one that had already rendered; start workers with the 'spawn' "
            "method (e.g. DataLoader(..., multiprocessing_context='spawn')) or render only in the workers",
            EXIT_INTERNAL,
        )
    _configure_environment()
    try:
        import moderngl
    except ImportError as error:  # pragma: no cover - depends on the installation
        raise StereoGeoError(
            "make-data needs moderngl: install the training extra, pip install 'stereogeo[train]'"
        ) from error
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as error:
        raise StereoGeoError(
            f"cannot create an EGL OpenGL context ({error}); on Debian/Ubuntu install: "
            f"apt-get install --no-install-recommends {' '.join(APT_PACKAGES)}",
            EXIT_INTERNAL,
        ) from error
    _CONTEXT, _CONTEXT_PID = ctx, os.getpid()
    return ctx


def projection_matrix(focal: float, width: int, height: int, near: float, far: float) -> np.ndarray:
    """OpenCV camera coordinates → GL clip coordinates [4 x 4], with the principal point at (w/2, h/2).

    A point (X, Y, Z) lands on GL window coordinate (f·X/Z + w/2 + 0.5, f·Y/Z + h/2 + 0.5), i.e. on the
    OpenCV pixel (f·X/Z + w/2, f·Y/Z + h/2) with GL row 0 holding image row 0.
    """
    a = (far + near) / (far - near)
    b = -2.0 * far * near / (far - near)
    return np.array(
        [
            [2.0 * focal / width, 0.0, 1.0 / width, 0.0],
            [0.0, 2.0 * focal / height, 1.0 / height, 0.0],
            [0.0, 0.0, a, b],
            [0.0, 0.0, 1.0, 0.0],
        ]
    )


def view_matrix(R_wc: np.ndarray, center: np.ndarray) -> np.ndarray:
    """World → camera [4 x 4] for a camera with rotation R_wc (world to camera) at ``center`` (world)."""
    M = np.eye(4)
    M[:3, :3] = R_wc
    M[:3, 3] = -R_wc @ center
    return M


def as_uniform(M: np.ndarray) -> bytes:
    """A row-major matrix as the column-major float32 bytes GL expects."""
    return np.ascontiguousarray(np.asarray(M, dtype=np.float32).T).tobytes()
