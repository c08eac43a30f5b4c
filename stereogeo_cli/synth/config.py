"""The sampler's settings: one dataclass with defaults, shared by make-data and the streaming dataset."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class SynthConfig:
    """What a synthetic stereo pair may look like. A sample is fully determined by (config, seed, index)."""

    short_side: int = 240  # image short side in pixels; the long side follows from the aspect ratio
    aspects: tuple[float, ...] = (4 / 3, 16 / 9, 1.0, 3 / 2)  # width / height of landscape images
    portrait_share: float = 0.2  # share of pairs with portrait images (aspect inverted)
    vfov_deg: tuple[float, float] = (20.0, 105.0)  # vertical field of view per camera, degrees
    equal_fov_share: float = 0.5  # share of pairs whose two cameras have the same vFoV
    baseline_m: tuple[float, float] = (0.05, 0.8)  # baseline range, metres, sampled log-uniform
    max_angle_deg: float = 45.0  # rig roll and pitch within ±this, degrees
    level_share: float = 0.35  # share of rigs near level (roll, pitch ~ N(0, 2°)), e.g. cars and robots
    parallel_share: float = 0.3  # share of rigs with R = I exactly (parallel cameras)
    toe_in_deg: float = 4.0  # largest relative rotation between the cameras otherwise, degrees
    panorama_share: float = 0.2  # share of pairs that are two crops of one panorama (T = 0)
    # a crop is at most this many times magnified against its panorama (narrower crops are widened): an
    # upsampled crop is blurred, and blur would tell the network a narrow lens, a cue that fails on real
    # photographs (docs/synth.md, "What the sampler draws")
    panorama_max_upsampling: float = 1.5
    outdoor_share: float = 0.5  # share of rendered scenes that are outdoor
    close_share: float = 0.25  # share of indoor scenes that are close range (a desk seen from 0.35–1.5 m)
    augment: float = 1.0  # strength of noise, blur and exposure augmentation (0 = none)
    msaa: int = 4  # multisample anti-aliasing samples (textures are also mipmapped)
    depth: bool = False  # also return z-depth maps (metres) of rendered pairs
    textures: Path | None = None  # folder of photos used as textures (default: scikit-image + procedural)
    panoramas: Path | None = None  # folder of equirectangular panoramas (default: procedural skies)
    texture_size: int = 512  # side of each texture layer, pixels
    texture_layers: int = 48  # texture layers in the per-process pool
    panorama_cache: int = 12  # panoramas kept uploaded per process

    def replace(self, **changes) -> SynthConfig:
        from dataclasses import replace

        return replace(self, **changes)


DEFAULT_CONFIG = SynthConfig()
