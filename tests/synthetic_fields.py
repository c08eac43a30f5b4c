"""Exact and noisy perspective fields of random cameras, for refiner tests and benchmarks."""

from __future__ import annotations

import numpy as np

from stereogeo_cli.geometry import focal_from_vfov, gravity_from_roll_pitch, latitude_field, up_field

SIZES = [(320, 240), (240, 320), (256, 256), (384, 216)]


def random_camera(rng: np.random.Generator, size=None):
    """(width, height, focal px, gravity [3], roll deg, pitch deg, vfov deg) of a random camera."""
    width, height = size or SIZES[rng.integers(len(SIZES))]
    vfov, roll, pitch = rng.uniform(20, 105), rng.uniform(-45, 45), rng.uniform(-45, 45)
    focal = float(focal_from_vfov(np.radians(vfov), height))
    return (
        width,
        height,
        focal,
        gravity_from_roll_pitch(np.radians(roll), np.radians(pitch)),
        roll,
        pitch,
        vfov,
    )


def noisy_fields(rng, width, height, focal, gravity, up_noise_deg=2.0, lat_noise_deg=1.0, outliers=0.2):
    """Fields with Gaussian angular noise, and a share of pixels replaced by random values at confidence 0.5.

    Returns up [H x W x 2], latitude [H x W], confidence [H x W] (used for both fields).
    """
    up = up_field(gravity, focal, width, height)
    angle = np.arctan2(up[..., 1], up[..., 0]) + np.radians(up_noise_deg) * rng.standard_normal(
        (height, width)
    )
    lat = latitude_field(gravity, focal, width, height) + np.radians(lat_noise_deg) * rng.standard_normal(
        (height, width)
    )
    bad = rng.random((height, width)) < outliers
    angle[bad] = rng.uniform(-np.pi, np.pi, bad.sum())
    lat[bad] = rng.uniform(-np.pi / 2, np.pi / 2, bad.sum())
    confidence = np.where(bad, 0.5, 1.0)
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1), lat, confidence
