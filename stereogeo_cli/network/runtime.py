"""Inference with the exported network: ONNX Runtime and NumPy only (this module never imports torch).

One :class:`FieldNetwork` holds one ``InferenceSession`` for the process; :meth:`FieldNetwork.predict`
resizes and crops each view as the model's metadata says, runs both views through the one graph and
returns each view's fields with the pixel coordinates of every field cell in the network-input image.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import platform
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stereogeo_cli.errors import StereoGeoError
from stereogeo_cli.geometry import (
    ResizeCrop,
    apply_resize_crop,
    quaternion_to_rotation,
    resize_crop_for_network,
)

VIEW_OUTPUTS = ("up", "latitude", "up_confidence", "latitude_confidence")
DEPTH_STRIDE = 8  # the depth head's cells (stereogeo_cli.network.model.DepthHead), in network-input pixels
REQUIRED_METADATA = ("input_short_side", "input_multiple", "output_stride")
CACHE_ENV = "STEREOGEO_CACHE_DIR"  # where optimised graphs are kept; set empty to keep none


@dataclass(frozen=True)
class ViewFields:
    """The network's perspective fields of one view, at the network's output stride.

    Field arrays are [h x w (x 2)] with h = H/stride, w = W/stride of the network input (W x H).
    """

    up: np.ndarray  # [h x w x 2] unit up-vectors, image axes (x right, y down)
    latitude: np.ndarray  # [h x w] radians
    up_confidence: np.ndarray  # [h x w] in (0, 1)
    latitude_confidence: np.ndarray  # [h x w] in (0, 1)
    pixel_xy: tuple[np.ndarray, np.ndarray]  # (x, y) [h x w] each: cell centres in network-input pixels
    resize_crop: ResizeCrop  # original image → network input; ``resize_crop.focal_to_input`` maps f back
    # a model with a depth head: per stride-8 cell log(depth / focal) and the log of its error's spread
    # [H/8 x W/8] (stereogeo_cli.network.model.DepthHead); None otherwise
    depth: np.ndarray | None = None
    depth_spread: np.ndarray | None = None

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the network-input image the fields and ``pixel_xy`` refer to."""
        return self.resize_crop.out_size


@dataclass(frozen=True)
class NetworkOutput:
    """Both views' fields and the pose head's relative pose, ``X_right = R @ X_left + T``."""

    left: ViewFields
    right: ViewFields
    quaternion: np.ndarray  # [4] (w, x, y, z), unit, w >= 0
    translation: np.ndarray  # [3] metres (the network's learned metric scale)

    @property
    def rotation(self) -> np.ndarray:
        """R [3 x 3] of the quaternion."""
        return quaternion_to_rotation(self.quaternion)


def cell_pixel_coordinates(height: int, width: int, stride: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel centres (x, y) [height x width] of the cells of a stride-``stride`` output grid.

    Cell (i, j) covers input pixels ``stride·j … stride·j + stride - 1``; its centre is
    ``x = stride·j + (stride - 1)/2`` (pixel (0, 0) is the centre of the top-left pixel).
    """
    offset = (stride - 1) / 2.0
    xs = np.arange(width, dtype=float) * stride + offset
    ys = np.arange(height, dtype=float) * stride + offset
    x, y = np.meshgrid(xs, ys)
    return x, y


def default_model_path() -> Path:
    """The shipped model: ``stereogeo_cli/models/stereogeo.onnx`` in an installed package (the wheel carries
    the repository's ``models/`` folder there), or ``models/stereogeo.onnx`` beside the package in a source
    checkout or an editable install."""
    package = Path(__file__).resolve().parent.parent
    candidates = [folder / "stereogeo.onnx" for folder in (package / "models", package.parent / "models")]
    return next((path for path in candidates if path.is_file()), candidates[0])


def model_version(path: str | os.PathLike) -> str:
    """The version name a model file records (``model_version`` in its metadata), and the start of its
    SHA-256 so that two exports of one name can be told apart."""
    network = FieldNetwork(path, threads=1)
    name = network.metadata.get("model_version", "unnamed")
    return f"{name} (sha256 {network.model_sha256[:12]})"


def cache_folder() -> Path | None:
    """The folder of optimised graphs: ``$STEREOGEO_CACHE_DIR`` (empty: none), else ``stereogeo`` in
    ``$XDG_CACHE_HOME`` or ``~/.cache``."""
    chosen = os.environ.get(CACHE_ENV)
    if chosen is not None:
        return Path(chosen) if chosen.strip() else None
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "stereogeo"


def optimised_graph_name(model_sha256: str, runtime_version: str) -> str:
    """The cache file name of a model's optimised graph. An optimised graph holds memory layouts chosen for
    one CPU by one ONNX Runtime version, so the name carries the model's SHA-256, the runtime's version and
    the CPU's instruction sets."""
    key = hashlib.sha256(f"{model_sha256}|{runtime_version}|{_cpu_signature()}".encode()).hexdigest()
    return f"graph-{key[:24]}.onnx"


def _cpu_signature() -> str:
    """The CPU's architecture and instruction-set flags (Linux's /proc/cpuinfo; elsewhere the processor
    name the platform gives)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as info:
            flags = next((line for line in info if line.startswith(("flags", "Features"))), "")
    except OSError:
        flags = ""
    return f"{platform.machine()}|{flags.strip() or platform.processor()}"


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a file (hex), read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


class FieldNetwork:
    """The exported StereoGeoNet in one ONNX Runtime session (CPU).

    Args:
        model_path: the ``.onnx`` file written by ``stereogeo export-onnx``.
        threads: intra-op threads of the session (0: ONNX Runtime's default, one per core).
    """

    def __init__(self, model_path: str | os.PathLike, threads: int = 0):
        import onnxruntime as ort

        self.path = Path(model_path)
        if not self.path.exists():
            raise StereoGeoError(f"model file not found: {self.path}")
        if not self.path.is_file():
            raise StereoGeoError(f"model path {self.path} is not a file")
        self._sha256: str | None = None
        self.graph_file = self.path  # the file the session's graph was read from (the model, or the cache's)
        try:
            self.session = self._open_session(ort, int(threads))
        except Exception as exc:  # onnxruntime raises its own exception types for unreadable models
            reason = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
            raise StereoGeoError(f"model file {self.path} is not a valid ONNX model: {reason}") from None
        self.metadata: dict[str, str] = dict(self.session.get_modelmeta().custom_metadata_map)
        missing = [k for k in REQUIRED_METADATA if k not in self.metadata]
        inputs = {i.name for i in self.session.get_inputs()}
        if missing or inputs != {"left", "right"}:
            raise StereoGeoError(
                f"model file {self.path} is not a stereogeo network "
                f"(inputs {sorted(inputs)}, missing metadata {missing})"
            )
        try:
            self.short_side = int(self.metadata["input_short_side"])
            self.multiple = int(self.metadata["input_multiple"])
            self.stride = int(self.metadata["output_stride"])
        except ValueError:
            raise StereoGeoError(f"model file {self.path} has invalid size metadata") from None
        self.output_names = [o.name for o in self.session.get_outputs()]

    def _open_session(self, ort, threads: int):
        """The model's session. ONNX Runtime's graph optimisation (fusions, this CPU's memory layouts) takes
        more of a cold start than anything but the first calibration; the optimised graph is kept in the
        cache folder (:func:`cache_folder`, :func:`optimised_graph_name`) and a later process loads it
        with no optimisation to redo: the same graph, the same outputs bit for bit. Without a usable cache
        folder the model is optimised in every process, as it is the first time."""

        def options(level, save_to: Path | None = None):
            chosen = ort.SessionOptions()
            chosen.intra_op_num_threads = threads
            chosen.graph_optimization_level = level
            chosen.log_severity_level = 3  # errors only: ONNX Runtime's warnings are not for our users
            if save_to is not None:
                chosen.optimized_model_filepath = str(save_to)
            return chosen

        cpu = ["CPUExecutionProvider"]
        folder = cache_folder()  # (no folder: the model file is not even hashed here)
        optimised = (
            None if folder is None else folder / optimised_graph_name(self.model_sha256, ort.__version__)
        )
        if optimised is not None and optimised.is_file():
            try:
                session = ort.InferenceSession(
                    str(optimised), options(ort.GraphOptimizationLevel.ORT_DISABLE_ALL), providers=cpu
                )
                self.graph_file = optimised
                return session
            except Exception:  # a damaged or foreign file: optimised again below, and replaced
                pass
        full = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        if optimised is None:
            return ort.InferenceSession(str(self.path), options(full), providers=cpu)
        partial = optimised.with_name(f".{optimised.name}.{os.getpid()}.partial")
        try:
            optimised.parent.mkdir(parents=True, exist_ok=True)
            session = ort.InferenceSession(str(self.path), options(full, partial), providers=cpu)
            os.replace(partial, optimised)  # whole or not at all, also with processes racing to write it
            return session
        except Exception:  # a cache folder this process may not write (or a model that fails: again below)
            with contextlib.suppress(OSError):
                partial.unlink(missing_ok=True)
            return ort.InferenceSession(str(self.path), options(full), providers=cpu)

    @property
    def model_sha256(self) -> str:
        """SHA-256 of the model file (hex), computed once."""
        if self._sha256 is None:
            self._sha256 = file_sha256(self.path)
        return self._sha256

    def prepare(self, image_rgb: np.ndarray) -> tuple[np.ndarray, ResizeCrop]:
        """RGB image [H x W x 3] uint8 → network input [1 x 3 x H' x W'] float32 in [0, 1], its ResizeCrop."""
        image = np.asarray(image_rgb)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise StereoGeoError(f"expected an RGB uint8 image [H x W x 3], got {image.dtype} {image.shape}")
        height, width = image.shape[:2]
        rc = resize_crop_for_network(width, height, self.short_side, self.multiple)
        net_image = apply_resize_crop(image, rc)
        tensor = net_image.transpose(2, 0, 1)[None].astype(np.float32) / np.float32(255.0)
        return np.ascontiguousarray(tensor), rc

    def predict(self, left_rgb: np.ndarray, right_rgb: np.ndarray, flip: bool = False) -> NetworkOutput:
        """Fields of both views and the relative pose of a stereo pair.

        Args:
            left_rgb, right_rgb: RGB images [H x W x 3] uint8; the two sizes may differ.
            flip: also run the mirrored pair and average each view's fields with the mirrored fields mapped
                back (test-time augmentation; twice the network time). The pose is the unmirrored run's.
        """
        left, rc_left = self.prepare(left_rgb)
        right, rc_right = self.prepare(right_rgb)
        values = self.session.run(self.output_names, {"left": left, "right": right})
        out = dict(zip(self.output_names, values, strict=True))
        if flip:
            mirrored = self.session.run(
                self.output_names,
                {
                    "left": np.ascontiguousarray(left[..., ::-1]),
                    "right": np.ascontiguousarray(right[..., ::-1]),
                },
            )
            out = average_with_mirrored(out, dict(zip(self.output_names, mirrored, strict=True)))
        views = {}
        for view, rc in (("left", rc_left), ("right", rc_right)):
            fields = {k: out[f"{view}_{k}"][0] for k in VIEW_OUTPUTS}
            h, w = fields["latitude"].shape
            views[view] = ViewFields(
                up=np.ascontiguousarray(fields["up"].transpose(1, 2, 0)),
                latitude=fields["latitude"],
                up_confidence=fields["up_confidence"],
                latitude_confidence=fields["latitude_confidence"],
                pixel_xy=cell_pixel_coordinates(h, w, self.stride),
                resize_crop=rc,
                # the depth head's output is the unmirrored run's (``flip`` averages the fields only)
                depth=out[f"{view}_depth"][0] if f"{view}_depth" in out else None,
                depth_spread=out[f"{view}_depth_spread"][0] if f"{view}_depth_spread" in out else None,
            )
        return NetworkOutput(
            views["left"],
            views["right"],
            out["quaternion"][0].astype(float),
            out["translation"][0].astype(float),
        )


def average_with_mirrored(
    out: dict[str, np.ndarray], mirrored: dict[str, np.ndarray]
) -> dict[str, np.ndarray]:
    """Average the fields of a pair with those of the horizontally mirrored pair, mapped back.

    Mirroring the input maps output cell j to cell w - 1 - j exactly (cell centres 4j + 1.5 and
    W - 1 - x coincide), flips the up vector's x and leaves the latitude unchanged.
    """
    merged = dict(out)
    for view in ("left", "right"):
        up_m = mirrored[f"{view}_up"][..., ::-1].copy()
        up_m[:, 0] *= -1.0
        up = out[f"{view}_up"] + up_m
        merged[f"{view}_up"] = up / np.maximum(np.linalg.norm(up, axis=1, keepdims=True), 1e-8)
        for key in ("latitude", "up_confidence", "latitude_confidence"):
            name = f"{view}_{key}"
            merged[name] = 0.5 * (out[name] + mirrored[name][..., ::-1])
    return merged
