"""Fields of view other than a mother-machine trench: agar pads and users' outlines.

A :class:`Field` says what :func:`~napari_symbac.scene.draw_scene` draws around the
cells when the geometry is not a trench (supplement section 13):

* ``"agar_pad"`` (13.2): the simulated field, no device, agar (media) everywhere the
  cells are not;
* ``"outline"``: the user's wall polylines drawn as PDMS of ``wall_thickness_um``,
  media elsewhere, over the walls' bounding box grown by a margin.

``"trench"`` and ``"chamber"`` (13.1, a wide trench open to the flow channel, in the
same coordinates as a trench) are drawn by the trench drawer: :func:`field_of`
returns ``None`` for them.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "OUTLINE_WALL_THICKNESS_UM",
    "TEXTURE_SEED_KEY",
    "Field",
    "add_media_texture",
    "field_of",
]

#: Default thickness of a drawn outline wall (um): the physics wall of the simulator
#: (a capsule of radius ``sim.geometry.OUTLINE_WALL_RADIUS_UM = 0.05`` um around the
#: polyline), so drawn PDMS and cells never overlap. The drawn line is its centre.
OUTLINE_WALL_THICKNESS_UM = 0.1

#: Second entry of the seed sequence ``[simulation seed, 2]`` of the background texture
#: (the rendering noise uses ``[seed, 1]``, see :func:`napari_symbac.pipeline.noise_rng`).
TEXTURE_SEED_KEY = 2


@dataclass(frozen=True)
class Field:
    """A rectangular field of view in the simulation's coordinates (not a trench).

    Parameters
    ----------
    width_um, height_um
        Size of the field of view (camera image = size / pixel size).
    origin_um
        Simulation coordinates ``(x, y)`` of the field's top-left corner (x to the
        right, y down the image rows).
    walls_um
        Device walls as polylines of ``(x, y)`` vertices in simulation coordinates,
        drawn as PDMS; empty for an agar pad (no device).
    wall_thickness_um
        Thickness of a drawn wall, centred on its polyline.
    depth_um
        Optical depth of the media layer (``s_media`` of eq. OPL2-3); the drawing
        functions use the trench depth so that a field and a trench rendered with the
        same intensities have the same cell / media contrast.
    """

    width_um: float
    height_um: float
    origin_um: tuple[float, float] = (0.0, 0.0)
    walls_um: tuple[tuple[tuple[float, float], ...], ...] = ()
    wall_thickness_um: float = OUTLINE_WALL_THICKNESS_UM
    depth_um: float = 1.2

    def __post_init__(self) -> None:
        for name in ("width_um", "height_um", "wall_thickness_um", "depth_um"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"Field.{name} must be a positive number, got {value!r}")
            object.__setattr__(self, name, float(value))
        try:
            ox, oy = (float(v) for v in self.origin_um)
        except (TypeError, ValueError) as err:
            raise ValueError(f"Field.origin_um must be (x, y), got {self.origin_um!r}") from err
        if not (math.isfinite(ox) and math.isfinite(oy)):
            raise ValueError(f"Field.origin_um must be finite, got {self.origin_um!r}")
        object.__setattr__(self, "origin_um", (ox, oy))
        walls = []
        for index, line in enumerate(self.walls_um):
            points = np.asarray(line, dtype=float)
            if points.ndim != 2 or points.shape[1] != 2 or len(points) < 2:
                raise ValueError(
                    f"Field.walls_um[{index}] must be at least two (x, y) vertices, got {line!r}"
                )
            if not np.all(np.isfinite(points)):
                raise ValueError(f"Field.walls_um[{index}] has non-finite vertices")
            walls.append(tuple((float(x), float(y)) for x, y in points))
        object.__setattr__(self, "walls_um", tuple(walls))


def field_of(simulation: Any) -> Field | None:
    """The field of view of a simulation's geometry, or ``None`` for a trench drawing.

    ``"trench"`` and ``"chamber"`` give ``None`` (drawn by the trench drawer with the
    settings' :class:`~napari_symbac.settings.TrenchGeometry`); ``"agar_pad"`` the
    :class:`~napari_symbac.settings.AgarPadGeometry` field from ``(0, 0)``;
    ``"outline"`` the bounding box of ``simulation.walls_um`` (or, if empty, of the
    settings' outline polylines) grown by ``max(exit_margin_um, wall thickness)``, so
    every cell the simulator keeps is inside it.

    Parameters
    ----------
    simulation
        A :class:`~napari_symbac.sim.Simulation` (anything with ``settings`` and
        ``walls_um``), or :class:`~napari_symbac.settings.SimulationSettings`.
    """
    settings = getattr(simulation, "settings", simulation)
    geometry = settings.geometry
    depth = settings.trench.depth_um
    if geometry in ("trench", "chamber"):
        return None
    if geometry == "agar_pad":
        pad = settings.agar_pad
        return Field(pad.field_width_um, pad.field_height_um, depth_um=depth)
    if geometry != "outline":
        raise ValueError(f"unknown geometry {geometry!r}")
    walls = tuple(getattr(simulation, "walls_um", ()) or ())
    if not walls:
        from napari_symbac.sim.geometry import outline_polylines_um

        walls = tuple(outline_polylines_um(settings.outline))
    points = np.concatenate([np.asarray(w, dtype=float) for w in walls])
    (x0, y0), (x1, y1) = points.min(axis=0), points.max(axis=0)
    margin = max(settings.outline.exit_margin_um, OUTLINE_WALL_THICKNESS_UM)
    return Field(
        float(x1 - x0 + 2 * margin),
        float(y1 - y0 + 2 * margin),
        origin_um=(float(x0 - margin), float(y0 - margin)),
        walls_um=walls,
        depth_um=depth,
    )


@functools.lru_cache(maxsize=16)
def field_images(
    field: Field, shape: tuple[int, int], border: int, px: float
) -> tuple[np.ndarray, np.ndarray]:
    """Open (media-fillable) and device fractions of every render pixel (read-only).

    A wall covers the pixels within ``wall_thickness_um / 2`` of its polyline, with a
    one-pixel linear ramp for anti-aliasing. Cached per field (every frame shares them).
    """
    ox, oy = field.origin_um
    yc = (np.arange(shape[0]) - border + 0.5) * px + oy
    xc = (np.arange(shape[1]) - border + 0.5) * px + ox
    device = np.zeros(shape, np.float32)
    half = field.wall_thickness_um / 2
    reach = half + 2 * px
    for line in field.walls_um:
        pts = np.asarray(line, dtype=float)
        for (ax, ay), (bx, by) in itertools.pairwise(pts):
            j0 = max(int(np.searchsorted(xc, min(ax, bx) - reach)), 0)
            j1 = min(int(np.searchsorted(xc, max(ax, bx) + reach)), shape[1])
            i0 = max(int(np.searchsorted(yc, min(ay, by) - reach)), 0)
            i1 = min(int(np.searchsorted(yc, max(ay, by) + reach)), shape[0])
            if j0 >= j1 or i0 >= i1:
                continue
            x = xc[None, j0:j1]
            y = yc[i0:i1, None]
            dx, dy = bx - ax, by - ay
            length2 = dx * dx + dy * dy
            if length2 > 0:
                t = np.clip(((x - ax) * dx + (y - ay) * dy) / length2, 0.0, 1.0)
            else:
                t = np.zeros(np.broadcast_shapes(x.shape, y.shape))
            d = np.hypot(x - (ax + t * dx), y - (ay + t * dy))
            cover = np.clip((half - d) / px + 0.5, 0.0, 1.0).astype(np.float32)
            np.maximum(device[i0:i1, j0:j1], cover, out=device[i0:i1, j0:j1])
    open_frac = (1.0 - device).astype(np.float32)
    open_frac.setflags(write=False)
    device.setflags(write=False)
    return open_frac, device


#: Octaves of a measured texture (``RenderSettings.texture_scale_um``): the lattice
#: spacing and half of it, the finer half as strong.
MEASURED_TEXTURE_OCTAVES = 2


@functools.lru_cache(maxsize=4)
def _texture(seed: int, shape: tuple[int, int], scale_px: float = 0.0) -> np.ndarray:
    from napari_symbac.optics.texture import perlin_texture, random_perlin_texture

    rng = np.random.default_rng(np.random.SeedSequence([seed, TEXTURE_SEED_KEY]))
    if scale_px > 0:
        texture = perlin_texture(
            shape, rng, scale_px=scale_px, octaves=MEASURED_TEXTURE_OCTAVES, persistence=0.5
        )
    else:
        texture = random_perlin_texture(shape, rng)
    texture.setflags(write=False)
    return texture


def add_media_texture(scene: Any, amplitude: float, seed: int, scale_um: float = 0.0) -> Any:
    """Perlin background texture of an agar pad (supplement 13.2.1) on the media image.

    The media fraction is multiplied by ``1 + amplitude * T`` (clipped at 0), with
    ``T`` a zero-mean, unit-s.d. :func:`~napari_symbac.optics.random_perlin_texture`
    at render resolution whose random parameters and gradients come from
    ``numpy.random.default_rng(SeedSequence([seed, 2]))``: the same seed gives the
    same texture, bit for bit, on every frame (the pad does not move). With
    ``scale_um > 0`` (``RenderSettings.texture_scale_um``, a texture measured on a
    recording) ``T`` is :func:`~napari_symbac.optics.perlin_texture` of that lattice
    spacing, :data:`MEASURED_TEXTURE_OCTAVES` octaves, from the same generator. The
    texture goes through the PSF like the rest of the sample. ``amplitude = 0``
    returns ``scene`` itself.
    """
    if not (math.isfinite(amplitude) and amplitude >= 0):
        raise ValueError(f"texture amplitude must be zero or positive, got {amplitude!r}")
    if not (math.isfinite(scale_um) and scale_um >= 0):
        raise ValueError(f"texture scale must be zero or positive (um), got {scale_um!r}")
    if amplitude == 0:
        return scene
    scale_px = scale_um / scene.pixel_size_um if scale_um > 0 else 0.0
    texture = _texture(int(seed), tuple(scene.shape), float(scale_px))
    gain = np.maximum(np.float32(1.0) + np.float32(amplitude) * texture, np.float32(0.0))
    return scene.replace_media(scene.media * gain)
