"""Headless OpenGL on the CPU: an EGL context on Mesa's software rasteriser (llvmpipe), and the projection.

One context per process, created lazily and reused (:func:`get_context`). The projection follows the
project's camera convention exactly: OpenCV axes (x right, y down, z forward), principal point at
(w/2, h/2) unless a camera says otherwise, pixel (0, 0) the centre of the top-left pixel. Frames are
rendered "upside down" in GL's window coordinates so that GL row 0 is image row 0 and no flip is needed
when reading back.

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


def projection_matrix(
    focal: float,
    width: int,
    height: int,
    near: float,
    far: float,
    fy: float | None = None,
    principal: tuple[float, float] | None = None,
) -> np.ndarray:
    """OpenCV camera coordinates → GL clip coordinates [4 x 4], with fx = ``focal``, fy = ``fy`` (default
    ``focal``) and the principal point ``principal`` (cx, cy) (default (w/2, h/2)).

    A point (X, Y, Z) lands on GL window coordinate (fx·X/Z + cx + 0.5, fy·Y/Z + cy + 0.5), i.e. on the
    OpenCV pixel (fx·X/Z + cx, fy·Y/Z + cy) with GL row 0 holding image row 0. (NDC x = 2·(u + 0.5)/w − 1,
    so the third column holds (2·cx + 1)/w − 1, written as 1/w + (2·cx − w)/w: exactly 1/w at the centre.)
    """
    a = (far + near) / (far - near)
    b = -2.0 * far * near / (far - near)
    fy = focal if fy is None else fy
    shift_x, shift_y = 1.0 / width, 1.0 / height
    if principal is not None:
        shift_x += (2.0 * principal[0] - width) / width
        shift_y += (2.0 * principal[1] - height) / height
    return np.array(
        [
            [2.0 * focal / width, 0.0, shift_x, 0.0],
            [0.0, 2.0 * fy / height, shift_y, 0.0],
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
