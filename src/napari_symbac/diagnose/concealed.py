"""Generator of recordings with a concealed effect, for the benchmark and the tests.

Each case renders a scene with the project's forward model and injects one effect
*physically* where the model allows it (a different camera for ``camera_noise``,
bent cells of eq. 1 for ``cell_curvature``,
moved cells for ``stage_drift``, Perlin media texture for ``background_texture``,
per-cell brightness for ``cell_intensity_variability``, part of the stain in the cell
envelope for ``envelope_stain`` (:func:`~napari_symbac.scene.envelope_stain`, its true
parameter the fraction drawn), a focus that varies over the
field for ``defocus_gradient``, clipping of the camera output for ``saturation``, dimmer
cells frame by frame for ``photobleaching``) and with the catalogue's stage otherwise
(``uneven_illumination``, ``halo``, ``stray_light``, ``fixed_pattern_noise``;
a change of the phase-ring contrast is absorbed by the fitted intensities and
apodisation, see docs/diagnosis.md). The amplitude is
scaled so that the largest single-pixel change of the noise-free image is ``fraction``
times the noise s.d. of that pixel (concealed: below the noise); ``camera_noise`` is a
12 % gain error and ``saturation`` a ceiling at the 10th-brightest pixel value.

The "true" parameter in the effect's own parametrisation is the fit of the effect's
model to the noise-free image (an oracle projection): for effects injected with their
own stage it is the injected value.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from napari_symbac.diagnose.model import BaseDesign, build_design, fit_model, variance
from napari_symbac.optics.forward import ForwardModel
from napari_symbac.scene import Field, Scene, draw_scene, envelope_stain
from napari_symbac.settings import Camera, Microscope, RenderSettings, TrenchGeometry
from napari_symbac.sim import FrameCells

__all__ = ["ConcealedCase", "base_settings", "make_case"]

PIXEL_UM = 0.065


@dataclass(frozen=True, eq=False)
class ConcealedCase:
    """A generated recording and what is hidden in it."""

    images: np.ndarray  # (T, Y, X) uint16
    design: BaseDesign  # oracle geometry, base settings
    effect: str | None
    fraction_of_sd: float
    modality: str
    geometry: str
    masked: bool
    true_magnitude: float


def base_settings(modality: str) -> tuple[Microscope, RenderSettings, Camera]:
    """Microscope, render settings and camera of the generated recordings."""
    microscope = Microscope(pixel_size_um=PIXEL_UM, modality=modality)  # type: ignore[arg-type]
    if modality == "phase":
        render = RenderSettings(
            cell_intensity=1400.0,
            media_intensity=2600.0,
            device_intensity=900.0,
            apodisation_sigma_um=0.6,
            defocus_sigma_um=0.15,
            ring_contrast=0.5,
            psf_offset=0.05,
            psf_radius_px=40,
        )
    elif modality == "brightfield":  # cells absorb 4 %, out of focus: a bright centre
        render = RenderSettings(
            cell_intensity=2500.0,
            media_intensity=2600.0,
            device_intensity=2300.0,
            defocus_sigma_um=0.15,
            defocus_contrast_um2=0.015,
            psf_radius_px=40,
        )
    else:
        render = RenderSettings(
            cell_intensity=2400.0,
            media_intensity=150.0,
            device_intensity=120.0,
            defocus_sigma_um=0.1,
            psf_radius_px=40,
        )
    return microscope, render, Camera()


def _cells(
    geometry: str, rng: np.random.Generator
) -> tuple[FrameCells, TrenchGeometry, Field | None, tuple]:
    if geometry == "trench":
        rows = 256
        trench = TrenchGeometry(
            length_um=rows * PIXEL_UM - 0.75, width_um=1.5, depth_um=1.2, margin_um=0.75
        )
        n = 6
        lengths = rng.uniform(2.0, 2.6, n)
        gaps = rng.uniform(0.05, 0.25, n)
        y = np.cumsum(lengths + gaps) - lengths / 2 + 0.1
        cells = FrameCells(
            ids=np.arange(1, n + 1),
            x_um=0.75 + rng.normal(0, 0.02, n),
            y_um=y,
            angle_rad=rng.normal(0, 0.04, n),
            length_um=lengths,
            width_um=np.full(n, 0.95),
        )
        return cells, trench, None, (rows, 46)
    size, n_cells = 144, 6
    extent = size * PIXEL_UM
    placed: list[tuple[float, float, float, float]] = []
    for _ in range(10_000):
        x, y = rng.uniform(1.4, extent - 1.4, 2)
        angle, length = rng.uniform(0, np.pi), rng.uniform(2.0, 2.6)
        if all(np.hypot(x - p[0], y - p[1]) > 0.5 * (length + p[3]) + 0.3 for p in placed):
            placed.append((x, y, angle, length))
            if len(placed) == n_cells:
                break
    else:
        raise RuntimeError("could not place the field's cells without overlap")
    arr = np.array(placed)
    cells = FrameCells(
        ids=np.arange(1, n_cells + 1),
        x_um=arr[:, 0],
        y_um=arr[:, 1],
        angle_rad=arr[:, 2],
        length_um=arr[:, 3],
        width_um=np.full(n_cells, 0.95),
    )
    trench = TrenchGeometry()
    return cells, trench, Field(extent, extent), (size, size)


def _draw(cells, trench, field, shape, microscope, render, curvature=None) -> Scene:
    if field is not None:
        return draw_scene(cells, trench, microscope, render, curvature, field=field)
    return draw_scene(cells, trench, microscope, render, curvature, camera_shape=shape)


def _shifted(cells: FrameCells, dx_um: float, dy_um: float) -> FrameCells:
    return dataclasses.replace(cells, x_um=cells.x_um + dx_um, y_um=cells.y_um + dy_um)


def _scale_to(delta: np.ndarray, sd: np.ndarray, fraction: float) -> float:
    peak = float(np.max(np.abs(delta) / sd))
    if peak <= 0:
        raise ValueError("the injected effect changed nothing")
    return fraction / peak


def make_case(
    effect: str | None,
    *,
    modality: str = "phase",
    geometry: str = "trench",
    fraction_of_sd: float = 0.5,
    masked: bool = False,
    n_frames: int = 1,
    seed: int = 0,
) -> ConcealedCase:
    """One generated recording with ``effect`` (``None``: a no-effect control).

    Parameters
    ----------
    effect
        Catalogue name, or ``None``.
    modality, geometry
        ``"phase"``/``"fluorescence"``/``"brightfield"``; ``"trench"`` (256 x 46) or
        ``"field"`` (144 x 144, 6 cells).
    fraction_of_sd
        Largest single-pixel change of the noise-free image, in noise s.d.
    masked
        Render with a larger, already-modelled difference on top (intensities 8 %
        and defocus 0.05 um off the base settings the diagnosis starts from).
    n_frames
        Frames (the series effects use at least 6).
    seed
        Everything random comes from ``numpy.random.default_rng(seed)``.
    """
    rng = np.random.default_rng(seed)
    microscope, render, camera = base_settings(modality)
    if effect in ("photobleaching", "stage_drift"):
        n_frames = max(n_frames, 6)
    cells, trench, field, shape = _cells(geometry, rng)
    truth_render = render
    if masked:
        truth_render = dataclasses.replace(
            render,
            cell_intensity=render.cell_intensity * 1.08,
            media_intensity=render.media_intensity * 0.97,
            defocus_sigma_um=render.defocus_sigma_um + 0.05,
        )
    scene = _draw(cells, trench, field, shape, microscope, render)
    scenes = [scene] * n_frames
    model = ForwardModel(microscope, truth_render, camera)
    clean = np.stack([model.render_clean(scene).astype(np.float64)] * n_frames)
    sd = np.sqrt(variance(clean, camera))
    design = build_design(scenes, microscope, render, camera)
    cam = camera
    clip = None
    column_offsets = None
    truth_param = np.nan
    if effect is None:
        signal = clean
    elif effect == "defocus_gradient":
        lo = model.with_render(
            dataclasses.replace(
                truth_render, defocus_sigma_um=max(truth_render.defocus_sigma_um - 0.1, 0.0)
            )
        )
        hi = model.with_render(
            dataclasses.replace(truth_render, defocus_sigma_um=truth_render.defocus_sigma_um + 0.1)
        )
        w = (
            np.linspace(0, 1, shape[0])[:, None]
            if geometry == "trench"
            else np.linspace(0, 1, shape[1])[None, :]
        )
        blend = (1 - w) * lo.render_clean(scene) + w * hi.render_clean(scene)
        delta = np.stack([blend] * n_frames) - clean
        signal = clean + _scale_to(delta, sd, fraction_of_sd) * delta
    elif effect == "camera_noise":
        cam = dataclasses.replace(camera, sensitivity_adu_per_e=camera.sensitivity_adu_per_e * 1.12)
        signal = clean
        truth_param = 0.12
    elif effect == "saturation":
        signal = clean
        clip = -1.0  # set from the noisy image below
    elif effect == "cell_intensity_variability":
        gains = 1.0 + rng.normal(0, 1, len(cells.ids))
        gain_map = np.ones(scene.shape, np.float32)
        for i, g in zip(cells.ids, gains):
            gain_map[scene.labels == i] = g
        probe = model.render_clean(
            scene.replace_cells(scene.cells * gain_map)
        ) - model.render_clean(scene)
        s = _scale_to(np.stack([probe] * n_frames), sd, fraction_of_sd)
        gain_map = np.ones(scene.shape, np.float32)
        for i, g in zip(cells.ids, gains):
            gain_map[scene.labels == i] = 1 + s * (g - 1)
        varied = scene.replace_cells(scene.cells * gain_map)
        signal = np.stack([model.render_clean(varied).astype(np.float64)] * n_frames)
    elif effect == "envelope_stain":
        probe = model.render_clean(envelope_stain(scene, 1.0)) - model.render_clean(scene)
        fraction = min(_scale_to(np.stack([probe] * n_frames), sd, fraction_of_sd), 1.0)
        stained = model.render_clean(envelope_stain(scene, fraction)).astype(np.float64)
        signal = np.stack([stained] * n_frames)
        truth_param = fraction
    elif effect == "background_texture":
        from napari_symbac.optics.texture import random_perlin_texture

        tex = random_perlin_texture(scene.shape, rng)
        probe = model.render_clean(
            scene.replace_media(scene.media * (1 + 0.05 * tex))
        ) - model.render_clean(scene)
        a = 0.05 * _scale_to(np.stack([probe] * n_frames), sd, fraction_of_sd)
        textured = scene.replace_media(
            np.maximum(scene.media * (1 + a * tex), 0).astype(np.float32)
        )
        signal = np.stack([model.render_clean(textured).astype(np.float64)] * n_frames)
    elif effect == "cell_curvature":
        bows = rng.choice([-1.0, 1.0], len(cells.ids)) * rng.uniform(0.5, 1.0, len(cells.ids))
        curved = _draw(
            cells,
            trench,
            field,
            shape,
            microscope,
            render,
            {int(i): (0.05 * b, 1.0, 0.0) for i, b in zip(cells.ids, bows)},
        )
        probe = model.render_clean(curved) - model.render_clean(scene)
        s = _scale_to(np.stack([probe] * n_frames), sd, fraction_of_sd)
        curved = _draw(
            cells,
            trench,
            field,
            shape,
            microscope,
            render,
            {int(i): (0.05 * s * b, 1.0, 0.0) for i, b in zip(cells.ids, bows)},
        )
        signal = np.stack([model.render_clean(curved).astype(np.float64)] * n_frames)
    elif effect == "stage_drift":
        t = np.arange(n_frames) - (n_frames - 1) / 2
        angle = rng.uniform(0, 2 * np.pi)

        def frames(speed_px: float) -> np.ndarray:
            return np.stack(
                [
                    model.render_clean(
                        _draw(
                            _shifted(
                                cells,
                                speed_px * tt * np.cos(angle) * PIXEL_UM,
                                speed_px * tt * np.sin(angle) * PIXEL_UM,
                            ),
                            trench,
                            field,
                            shape,
                            microscope,
                            render,
                        )
                    ).astype(np.float64)
                    for tt in t
                ]
            )

        speed = 0.1 * _scale_to(frames(0.1) - clean, sd, fraction_of_sd)
        signal = frames(speed)
        truth_param = speed
    elif effect == "photobleaching":
        t = np.arange(n_frames)
        cells_only = ForwardModel(
            microscope,
            dataclasses.replace(truth_render, media_intensity=0.0, device_intensity=0.0),
            camera,
        )
        cell_part = np.stack([cells_only.render_clean(scene).astype(np.float64)] * n_frames)
        probe = cell_part * (np.exp(-0.01 * t) - 1)[:, None, None]
        rate = 0.01 * _scale_to(probe, sd, fraction_of_sd)
        signal = clean + cell_part * (np.exp(-rate * t) - 1)[:, None, None]
        truth_param = rate
    else:
        from napari_symbac.diagnose.effects import CATALOGUE

        eff = CATALOGUE[effect](design.geometry)
        direction = eff.direction(rng)
        parts = np.asarray(design.components) * design.intensities[:, None, None, None]
        probe = eff.mean(direction, clean, parts, design.geometry) - clean
        theta = direction * _scale_to(probe, sd, fraction_of_sd)
        signal = eff.mean(theta, clean, parts, design.geometry)
        if effect == "fixed_pattern_noise":
            column_offsets = eff.column_offsets(theta)
            signal = clean
    noise_model = ForwardModel(microscope, truth_render, cam)
    images = np.stack(
        [noise_model.add_noise(np.maximum(f, 0).astype(np.float32), rng) for f in signal]
    )
    if column_offsets is not None:
        images = np.clip(np.rint(images + column_offsets[None, None, :]), 0, camera.max_adu).astype(
            np.uint16
        )
    if clip is not None:
        # the 10 brightest pixels are clipped: a ceiling low enough to matter (a clip
        # hidden below the noise leaves one or two pixels there, which no test can tell
        # from chance), so their change can exceed the noise s.d.
        clip = float(np.sort(images, axis=None)[-10])
        images = np.minimum(images, np.uint16(clip))
    if effect is not None and not np.isfinite(truth_param):
        truth_param = oracle_magnitude(effect, design, signal, clip, column_offsets)
    return ConcealedCase(
        images, design, effect, fraction_of_sd, modality, geometry, masked, float(truth_param)
    )


def oracle_magnitude(
    effect: str, design: BaseDesign, signal: np.ndarray, clip, column_offsets
) -> float:
    """The effect model's magnitude fitted to the noise-free image (the truth to recover)."""
    from napari_symbac.diagnose.effects import CATALOGUE

    eff = CATALOGUE[effect](design.geometry)
    eff.random_field = False  # noise-free: the plain projection, nothing to shrink
    if effect == "saturation":
        return float(clip)
    y = signal.copy()
    if column_offsets is not None:
        y = y + column_offsets[None, None, :]
    model = fit_model(design, y, np.ones(y.shape, bool), [(eff, eff.null())], rounds=3)
    theta = model.effects[0][1]
    return float(eff.magnitude(eff.summary(theta, model.mu)))
