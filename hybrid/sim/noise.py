"""Smooth random signals used by the colon, trajectory and texture generators."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d


def smooth_noise(rng: np.random.Generator, n: int, sigma: float, dims: int = 1) -> np.ndarray:
    """(n, dims) Gaussian-filtered white noise with unit standard deviation per dimension.

    sigma is the filter width in samples; the signal varies on that scale.
    """
    pad = int(4 * sigma) + 1
    white = rng.standard_normal((n + 2 * pad, dims))
    smooth = gaussian_filter1d(white, sigma, axis=0, mode="wrap")[pad:pad + n]
    return smooth / smooth.std(axis=0, keepdims=True).clip(1e-12)


def periodic_noise_2d(rng: np.random.Generator, shape: tuple[int, int], scale: float) -> np.ndarray:
    """Zero-mean, unit-std 2-D noise with features of about `scale` samples, periodic."""
    spectrum = np.fft.fft2(rng.standard_normal(shape))
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.fftfreq(shape[1])[None, :]
    spectrum *= np.exp(-0.5 * (fx**2 + fy**2) * (2 * np.pi * scale / 2.0) ** 2)
    field = np.fft.ifft2(spectrum).real
    return (field - field.mean()) / max(field.std(), 1e-12)
