"""Sensor models: phone RGB (exposure, shot and read noise, sRGB, 8 bit) and FLIR radiometric
thermal counts (TemperatureLinear, NETD noise, 0 reserved for "no measurement")."""
from __future__ import annotations

import numpy as np

FULL_WELL_E = 2000.0  # electrons at full scale: phone-sized pixels after binning
READ_NOISE_E = 4.0
EXPOSURE = 0.8        # linear radiance -> sensor fraction in normal light


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear [0, 1] -> sRGB [0, 1] (IEC 61966-2-1)."""
    linear = np.clip(linear, 0.0, 1.0)
    return np.where(linear <= 0.0031308, 12.92 * linear,
                    1.055 * np.power(linear, 1 / 2.4) - 0.055)


def phone_rgb(radiance: np.ndarray, light: float, gain: float,
              rng: np.random.Generator | None) -> np.ndarray:
    """Linear radiance (H, W, 3) -> uint8 sRGB; shot + read noise when rng is given.

    `light` scales what reaches the sensor (low light: few electrons, relatively more noise) and
    `gain` is the amplification the phone applies afterwards (it brightens the noise too).
    """
    signal = radiance * (EXPOSURE * light)
    if rng is not None:
        electrons = signal * FULL_WELL_E
        sigma = np.sqrt(np.maximum(electrons, 0) + READ_NOISE_E ** 2)
        signal = (electrons + sigma * rng.standard_normal(electrons.shape)) / FULL_WELL_E
    return np.round(srgb_encode(signal * gain) * 255).astype(np.uint8)


def thermal_counts(kelvin: np.ndarray, rng: np.random.Generator | None, scale_k: float = 0.01,
                   netd_k: float = 0.04) -> np.ndarray:
    """Kelvin (H, W) -> uint16 counts of `scale_k` kelvin with NETD Gaussian noise (if rng).

    Counts are clipped to [1, 65535]: 0 means "no measurement" in the dataset format, and a
    NaN input (nothing measured) becomes 0.
    """
    kelvin = np.asarray(kelvin, np.float64)
    noisy = kelvin if rng is None else kelvin + netd_k * rng.standard_normal(kelvin.shape)
    counts = np.clip(np.round(noisy / scale_k), 1, 65535)
    return np.where(np.isfinite(kelvin), counts, 0).astype(np.uint16)
