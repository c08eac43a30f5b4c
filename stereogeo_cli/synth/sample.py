"""One synthetic stereo pair, fully determined by (config, seed, index): the API training code uses."""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

import cv2
import numpy as np

from stereogeo_cli.synth.config import SynthConfig
from stereogeo_cli.synth.render import Renderer
from stereogeo_cli.synth.rigs import Rig, RigSample, sample_rig
from stereogeo_cli.synth.scenes import build_scene
from stereogeo_cli.synth.textures import list_images

_RENDERERS: dict[tuple, Renderer] = {}
SCENE_ATTEMPTS = 3  # scene placements tried before a blank-looking left view is accepted
MIN_CORNER_DENSITY = 10.0  # FAST corners per 10,000 pixels below which a view counts as blank
_NOISE = np.random.default_rng(0x5EED).standard_normal(1 << 22, dtype=np.float32)  # sensor noise table


@dataclass(frozen=True)
class StereoSample:
    """A rendered pair and its exact ground truth.

    left, right: [H x W x 3] uint8 RGB (both views have the same size).
    calib: the calib.jsonl record (id, left, right, R, T, notes; docs/synth.md, "What it writes") plus
        "rectified", "kind", "scene", "seed", "index", "baseline_m", "vfov_deg".
    depth_left, depth_right: [H x W] float32 z-depth in metres (0 = panorama / nothing), or None.
    """

    left: np.ndarray
    right: np.ndarray
    calib: dict
    depth_left: np.ndarray | None = None
    depth_right: np.ndarray | None = None

    @property
    def id(self) -> str:
        return self.calib["id"]


def sample_id(index: int) -> str:
    """The pair id of an index: file names left/<id>.png and right/<id>.png."""
    return f"{index:06d}"


def get_renderer(seed: int, config: SynthConfig) -> Renderer:
    """The process's renderer for this seed and configuration (built on first use, then reused)."""
    key = (
        os.getpid(),
        seed,
        config.texture_size,
        config.texture_layers,
        config.textures,
        config.panoramas,
        config.panorama_cache,
        config.msaa,
    )
    if key not in _RENDERERS:
        for old in [k for k in _RENDERERS if k[0] != os.getpid()]:  # inherited through fork: unusable
            del _RENDERERS[old]
        panoramas = list_images(config.panoramas) if config.panoramas is not None else None
        _RENDERERS[key] = Renderer(
            seed,
            config.texture_size,
            config.texture_layers,
            config.textures,
            panoramas,
            config.panorama_cache,
            config.msaa,
        )
    return _RENDERERS[key]


@dataclass(frozen=True)
class Exposure:
    """Photometric settings shared by both cameras of a pair (each camera deviates a little from them)."""

    gain: float
    gamma: float
    white_balance: tuple[float, float, float]

    @staticmethod
    def sample(rng: np.random.Generator, strength: float) -> Exposure:
        wb = np.exp(rng.normal(0.0, 0.05 * strength, 3))
        return Exposure(
            float(np.exp(rng.normal(0.0, 0.25 * strength))),
            float(np.exp(rng.normal(0.0, 0.12 * strength))),
            tuple(float(v) for v in wb),
        )


def augment(
    rng: np.random.Generator,
    image: np.ndarray,
    strength: float,
    exposure: Exposure | None = None,
    noise_rng: np.random.Generator | None = None,
    blur_share: float = 0.3,
) -> np.ndarray:
    """Exposure, gamma, white balance, occasional blur and sensor noise on an [H x W x 3] uint8 image.

    noise_rng: where the noise pattern is drawn from (default ``rng``). A sequence passes the same ``rng``
    state for every frame of a camera (the same photometric response and noise level) and a fresh
    ``noise_rng`` per frame (new noise).
    blur_share: the chance of a Gaussian blur (σ 0.3–1.1 px) at strength 1; the draws are the same for
    any value, so 0 changes nothing else.
    """
    if strength <= 0:
        return image
    exposure = exposure or Exposure(1.0, 1.0, (1.0, 1.0, 1.0))
    gamma = exposure.gamma * float(np.exp(rng.normal(0.0, 0.03 * strength)))
    gains = (
        exposure.gain
        * np.asarray(exposure.white_balance)
        * np.exp(rng.normal(0.0, 0.06 * strength) + rng.normal(0.0, 0.015 * strength, 3))
    )
    levels = np.arange(256, dtype=np.float64) / 255.0
    lut = np.clip(255.0 * levels[:, None] ** gamma * gains[None, :] + 0.5, 0, 255).astype(np.uint8)
    out = cv2.LUT(image, lut.reshape(256, 1, 3))
    if rng.random() < blur_share * strength:
        out = cv2.GaussianBlur(out, (0, 0), float(rng.uniform(0.3, 1.1)))
    sigma = float(rng.uniform(0.0, 3.0 * strength))
    offset = int((noise_rng or rng).integers(0, _NOISE.size))
    if sigma > 0.3:
        n = out.size
        if n <= _NOISE.size // 2:  # a window of a fixed table of normals: far cheaper than drawing them
            start = offset % (_NOISE.size - n)
            noise = _NOISE[start : start + n].reshape(out.shape)
        else:
            noise = (noise_rng or rng).standard_normal(out.shape, dtype=np.float32)
        out = cv2.scaleAdd(noise, sigma, out.astype(np.float32) + 0.5)
        out = np.clip(out, 0, 255).astype(np.uint8)
    return out


def corner_density(image: np.ndarray) -> float:
    """FAST corners (threshold 12) per 10,000 pixels of an [H x W x 3] uint8 image: ~0 for a bare wall."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    return len(cv2.FastFeatureDetector_create(threshold=12).detect(grey)) * 1e4 / grey.size


def _calib(index: int, seed: int, rig: Rig, kind: str, scene: str, vfovs: tuple[float, float]) -> dict:
    R, T = rig.R, rig.T
    baseline = float(np.linalg.norm(T))
    what = "two perspective crops of one panorama (pure rotation, T = 0)" if kind == "panorama" else "render"
    return {
        "id": sample_id(index),
        "left": rig.left.to_calib(),
        "right": rig.right.to_calib(),
        "R": R.tolist(),
        "T": [float(v) for v in T],
        "rectified": "no",
        "notes": f"stereogeo make-data {what}; scene {scene}, seed {seed}, index {index}; undistorted",
        "kind": kind,
        "scene": scene,
        "seed": int(seed),
        "index": int(index),
        "baseline_m": baseline,
        "vfov_deg": [float(np.degrees(v)) for v in vfovs],
    }


def _panorama_rig(rs: RigSample, cfg: SynthConfig, panorama_width: int) -> RigSample:
    """Crops: no translation, and no narrower vFoV than ``cfg.panorama_max_upsampling`` allows (the crop's
    pixels at most that many times smaller than the panorama's)."""
    low = np.radians(min(cfg.vfov_deg[1], rs.height * 360.0 / (cfg.panorama_max_upsampling * panorama_width)))
    lo_cfg, hi = np.radians(cfg.vfov_deg[0]), np.radians(cfg.vfov_deg[1])

    def remap(v: float) -> float:
        return float(v) if v >= low else float(low + (v - lo_cfg) / max(hi - lo_cfg, 1e-9) * (hi - low))

    return replace(rs, vfov_left=remap(rs.vfov_left), vfov_right=remap(rs.vfov_right), offset=np.zeros(3))


def sample_pair(
    seed: int,
    index: int,
    config: SynthConfig | None = None,
    renderer: Renderer | None = None,
    kind: str | None = None,
) -> StereoSample:
    """Render pair ``index`` of the dataset ``seed``: the same arguments always give the same bytes.

    kind: force "panorama" or a scene kind ("room", "corridor", "desk", "street", "open"); by default
    drawn from the config's shares (panorama crops only when ``config.panoramas`` is set).
    """
    cfg = config or SynthConfig()
    renderer = renderer or get_renderer(seed, cfg)
    rng = np.random.default_rng([seed, index])
    use_panorama = rng.random() < cfg.panorama_share and bool(renderer.sky_choices["panorama"])
    outdoor = rng.random() < cfg.outdoor_share
    scene_kind = (
        ("street" if rng.random() < 0.7 else "open")
        if outdoor
        else ("room" if rng.random() < 0.75 else "corridor")
    )
    # its own stream: every other draw of the pair is the same whatever close_share is, so close_share = 0
    # renders exactly the pairs of a sampler without desk scenes
    if not outdoor and np.random.default_rng([seed, index, 2]).random() < cfg.close_share:
        scene_kind = "desk"
    if kind is not None:
        use_panorama, scene_kind = kind == "panorama", kind
    rig_sample = sample_rig(rng, cfg)
    outdoor = scene_kind in ("street", "open")
    choices = renderer.sky_choices["panorama" if use_panorama else "outdoor" if outdoor else "window"]
    sky_index = choices[min(int(rng.random() * len(choices)), len(choices) - 1)]
    sky_yaw = float(rng.random())
    exposure = Exposure.sample(rng, cfg.augment)
    aug_rng = np.random.default_rng([seed, index, 1])
    depth_left = depth_right = None
    if use_panorama:
        rig_sample = _panorama_rig(rig_sample, cfg, renderer.panorama_width(sky_index))
        rig = rig_sample.place(np.zeros(3), float(rng.uniform(0, 2 * np.pi)))
        left = renderer.render_color(rig.left, sky_index, sky_yaw)
        right = renderer.render_color(rig.right, sky_index, sky_yaw)
        calib = _calib(
            index,
            seed,
            rig,
            "panorama",
            renderer.sky_name(sky_index),
            (rig_sample.vfov_left, rig_sample.vfov_right),
        )
        if cfg.depth:
            depth_left = np.zeros(left.shape[:2], np.float32)
            depth_right = np.zeros(right.shape[:2], np.float32)
    else:
        for attempt in range(SCENE_ATTEMPTS):
            scene = build_scene(rng, rig_sample, renderer.materials, scene_kind, baseline_m=cfg.baseline_m)
            rig = scene.rig
            vaos = renderer.upload(scene)
            left = renderer.render_color(rig.left, sky_index, sky_yaw, scene, vaos)
            if attempt == SCENE_ATTEMPTS - 1 or corner_density(left) >= MIN_CORNER_DENSITY:
                break
            renderer.release(vaos)  # a blank view (a bare wall, a clear sky): place the rig anew
        try:
            right = renderer.render_color(rig.right, sky_index, sky_yaw, scene, vaos)
            if cfg.depth:
                depth_left = renderer.render_depth(rig.left, scene, vaos)
                depth_right = renderer.render_depth(rig.right, scene, vaos)
        finally:
            renderer.release(vaos)
        calib = _calib(index, seed, rig, "render", scene_kind, (rig_sample.vfov_left, rig_sample.vfov_right))
    left = augment(aug_rng, left, cfg.augment, exposure)
    right = augment(aug_rng, right, cfg.augment, exposure)
    return StereoSample(left, right, calib, depth_left, depth_right)
