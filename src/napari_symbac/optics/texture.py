"""Perlin-type background texture for agar pads (supplement section 13.2.1)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["perlin_texture", "random_perlin_texture", "texture_stage"]


def _fade(t: np.ndarray) -> np.ndarray:
    return t * t * t * (t * (t * 6 - 15) + 10)


def _gradient_noise(shape: tuple[int, int], cell_px: float, rng: np.random.Generator) -> np.ndarray:
    """One octave of 2-D gradient (Perlin) noise with lattice spacing ``cell_px``."""
    rows, cols = shape
    ny = math.ceil(rows / cell_px) + 2
    nx = math.ceil(cols / cell_px) + 2
    angles = rng.uniform(0.0, 2 * math.pi, size=(ny, nx))
    gy, gx = np.sin(angles), np.cos(angles)
    y = np.arange(rows) / cell_px + rng.uniform(0, 1)
    x = np.arange(cols) / cell_px + rng.uniform(0, 1)
    y0 = np.floor(y).astype(int)
    x0 = np.floor(x).astype(int)
    ty = (y - y0)[:, None]
    tx = (x - x0)[None, :]
    out = np.zeros(shape)
    corners = {}
    for dy in (0, 1):
        for dx in (0, 1):
            iy = (y0 + dy)[:, None]
            ix = (x0 + dx)[None, :]
            corners[dy, dx] = gy[iy, ix] * (ty - dy) + gx[iy, ix] * (tx - dx)
    uy, ux = _fade(ty), _fade(tx)
    top = corners[0, 0] + ux * (corners[0, 1] - corners[0, 0])
    bottom = corners[1, 0] + ux * (corners[1, 1] - corners[1, 0])
    out = top + uy * (bottom - top)
    return out


def perlin_texture(
    shape: tuple[int, int],
    rng: np.random.Generator,
    scale_px: float = 32.0,
    octaves: int = 4,
    persistence: float = 0.5,
    lacunarity: float = 2.0,
) -> np.ndarray:
    """Fractal Perlin noise (Perlin 1985/2002), normalised to zero mean and unit s.d.

    Parameters
    ----------
    shape
        ``(rows, columns)``.
    rng
        All random draws (gradients, lattice offsets) come from it.
    scale_px
        Lattice spacing of the first (coarsest) octave, in pixels.
    octaves
        Number of octaves summed.
    persistence
        Amplitude ratio between successive octaves.
    lacunarity
        Frequency ratio between successive octaves.

    Returns
    -------
    numpy.ndarray
        float32 texture.
    """
    if len(shape) != 2 or min(shape) < 1:
        raise ValueError(f"shape must be (rows, columns) with positive sizes, got {shape!r}")
    if not (isinstance(octaves, (int, np.integer)) and octaves >= 1):
        raise ValueError(f"octaves must be an integer >= 1, got {octaves!r}")
    for name, value in (
        ("scale_px", scale_px),
        ("persistence", persistence),
        ("lacunarity", lacunarity),
    ):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be positive, got {value!r}")
    total = np.zeros(shape)
    amplitude, cell = 1.0, float(scale_px)
    for _ in range(octaves):
        total += amplitude * _gradient_noise(shape, max(cell, 1.0), rng)
        amplitude *= persistence
        cell /= lacunarity
    total -= total.mean()
    sd = total.std()
    return (total / sd if sd > 0 else total).astype(np.float32)


def random_perlin_texture(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """Perlin texture with randomised parameters (section 13.2.1).

    Draws ``scale_px ~ U(0.1, 0.5) * min(shape)``, ``octaves`` in 3..6,
    ``persistence ~ U(0.35, 0.7)`` and ``lacunarity ~ U(1.6, 2.4)`` from ``rng``.
    """
    scale = rng.uniform(0.1, 0.5) * min(shape)
    octaves = int(rng.integers(3, 7))
    persistence = rng.uniform(0.35, 0.7)
    lacunarity = rng.uniform(1.6, 2.4)
    return perlin_texture(shape, rng, scale, octaves, persistence, lacunarity)


def texture_stage(texture: np.ndarray, amplitude: float) -> Any:
    """A forward-model stage multiplying the clean image by ``1 + amplitude * texture``.

    ``texture`` must have the camera shape (e.g. from :func:`perlin_texture`).
    """
    from napari_symbac.optics.forward import Stage

    texture = np.asarray(texture, dtype=np.float32)
    if not math.isfinite(amplitude):
        raise ValueError(f"amplitude must be finite, got {amplitude!r}")

    def apply(image: np.ndarray, scene: Any) -> np.ndarray:
        if image.shape != texture.shape:
            raise ValueError(f"texture shape {texture.shape} differs from image {image.shape}")
        return image * (1 + np.float32(amplitude) * texture)

    return Stage("texture", False, {"amplitude": amplitude}, apply)
