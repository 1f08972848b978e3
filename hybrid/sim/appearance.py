"""Mucosa appearance: named styles and a procedural texture over the unrolled colon wall.

The texture is a map over surface coordinates (ℓ, θ·r̄) in cm, periodic around the lumen:
colour variation at three scales plus branching blood vessels. The renderer evaluates it at
each ray's hit point.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from hybrid.sim.noise import periodic_noise_2d

TEXELS_PER_CM = 40.0
"""Texture resolution on the wall."""


@dataclass(frozen=True)
class Style:
    """Palette, light and sensor of one simulated endoscope and bowel."""

    name: str
    base_rgb: tuple[float, float, float]
    """Mean mucosa albedo (linear RGB, 0..1)."""
    variation: float
    """Relative amplitude of the colour variation."""
    vessel_rgb: tuple[float, float, float]
    """Albedo of blood vessels."""
    vessel_strength: float
    """Opacity of the largest vessels."""
    vessels_per_cm2: float
    """Density of vessel trees on the wall."""
    light_gain: float
    """Diffuse irradiance at 2 cm from the light, facing it."""
    ambient: float
    """Light that reaches everywhere (inter-reflection)."""
    specular: float
    """Strength of the specular highlight (wet mucosa)."""
    shininess: float
    """Phong exponent of the highlight."""
    vignetting: float
    """Brightness lost at the image corners (fraction)."""
    blur_sigma_px: float
    """Optical blur, in pixels of a 160-pixel-wide image (scaled with the width)."""
    noise_std: float
    """Sensor noise standard deviation (0..1 scale, before quantisation)."""
    gamma: float
    """Display gamma."""


STYLES: dict[str, Style] = {
    "pink": Style("pink", base_rgb=(0.80, 0.36, 0.32), variation=0.15,
                  vessel_rgb=(0.45, 0.06, 0.10), vessel_strength=0.6, vessels_per_cm2=0.8,
                  light_gain=1.0, ambient=0.03, specular=0.5, shininess=40.0, vignetting=0.35,
                  blur_sigma_px=0.5, noise_std=0.01, gamma=2.2),
    "dusk": Style("dusk", base_rgb=(0.70, 0.42, 0.22), variation=0.25,
                  vessel_rgb=(0.40, 0.16, 0.08), vessel_strength=0.45, vessels_per_cm2=0.5,
                  light_gain=0.7, ambient=0.01, specular=1.0, shininess=80.0, vignetting=0.55,
                  blur_sigma_px=1.0, noise_std=0.03, gamma=1.9),
    # Narrow-band-imaging-like: teal mucosa, dense dark vessels, dim and noisy. Neither the
    # depth nor the coverage networks are trained on it: the shifted domain for CORAL.
    "nbi": Style("nbi", base_rgb=(0.30, 0.50, 0.48), variation=0.20,
                 vessel_rgb=(0.20, 0.10, 0.06), vessel_strength=0.75, vessels_per_cm2=1.6,
                 light_gain=0.6, ambient=0.02, specular=0.6, shininess=50.0, vignetting=0.5,
                 blur_sigma_px=0.8, noise_std=0.035, gamma=2.2),
}
"""Appearance styles, for simulator-to-simulator domain-shift studies."""


def get_style(name: str) -> Style:
    if name not in STYLES:
        raise ValueError(f"unknown style {name!r}; choose one of {sorted(STYLES)}")
    return STYLES[name]


def make_texture(length_cm: float, circumference_cm: float, style: Style,
                 rng: np.random.Generator) -> np.ndarray:
    """(rows along ℓ, columns around θ, 3) float32 albedo, periodic around θ."""
    rows = int(np.ceil(length_cm * TEXELS_PER_CM)) + 2
    cols = int(np.ceil(circumference_cm * TEXELS_PER_CM))
    shade = sum(w * periodic_noise_2d(rng, (rows, cols), s * TEXELS_PER_CM)
                for w, s in ((0.6, 1.5), (0.3, 0.4), (0.15, 0.08)))
    tint = periodic_noise_2d(rng, (rows, cols), 2.0 * TEXELS_PER_CM)
    base = np.asarray(style.base_rgb, dtype=np.float32)
    albedo = base * (1 + style.variation * shade[..., None])
    albedo[..., 2] *= 1 + 0.5 * style.variation * tint  # slow bluish/yellowish drift
    vessels = _vessel_map(rows, cols, length_cm * circumference_cm * style.vessels_per_cm2, rng)
    alpha = (style.vessel_strength * vessels)[..., None]
    albedo = (1 - alpha) * albedo + alpha * np.asarray(style.vessel_rgb, dtype=np.float32)
    return albedo.clip(0.0, 1.0).astype(np.float32)


def _vessel_map(rows: int, cols: int, count: float, rng: np.random.Generator) -> np.ndarray:
    """(rows, cols) float 0..1 opacity of branching vessels drawn as smooth random walks."""
    canvas = np.zeros((rows, 3 * cols), dtype=np.uint8)  # three copies side by side: wraps θ
    step = 0.08 * TEXELS_PER_CM
    trees = [(rng.uniform(0, rows), rng.uniform(0, cols), rng.uniform(0, 2 * np.pi), 4)
             for _ in range(rng.poisson(count))]
    while trees:
        r, c, heading, width = trees.pop()
        length = int(rng.uniform(0.5, 3.0) * width / 2 * TEXELS_PER_CM / step)
        turns = np.cumsum(rng.normal(0.0, 0.25, length))
        path = np.stack([c + np.cumsum(step * np.cos(heading + turns)),
                         r + np.cumsum(step * np.sin(heading + turns))], axis=1)
        level = int(60 + 195 * width / 4)
        for shift in (0, cols, 2 * cols):
            pts = np.round((path + [shift, 0]) * 4).astype(np.int32)  # 2 fractional bits
            cv2.polylines(canvas, [pts], False, level, max(1, width), cv2.LINE_AA, shift=2)
        if width > 1:
            for k in rng.integers(0, length, rng.integers(1, 4)):
                trees.append((path[k, 1], path[k, 0] % cols, heading + turns[k]
                              + rng.choice([-1, 1]) * rng.uniform(0.4, 1.2), width - 1))
    canvas = cv2.GaussianBlur(canvas, (0, 0), 0.8)
    wrapped = np.maximum.reduce([canvas[:, :cols], canvas[:, cols:2 * cols], canvas[:, 2 * cols:]])
    return wrapped.astype(np.float32) / 255.0
