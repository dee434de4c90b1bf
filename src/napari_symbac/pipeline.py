"""The end-to-end path: simulate -> draw scenes -> render, shared by CLI, GUI and demo.

Each function here is the public, headless call behind a widget or a CLI command.
"""

from __future__ import annotations

import dataclasses
import os
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from napari_symbac.optics import ForwardModel
from napari_symbac.scene import (
    Field,
    Scene,
    add_debris,
    add_media_texture,
    debris_rng,
    depth_stain,
    draw_scene,
    envelope_stain,
    field_of,
    scale_cells,
)
from napari_symbac.settings import Microscope, PipelineSettings, RenderSettings
from napari_symbac.sim import Simulation

__all__ = [
    "RenderedSeries",
    "apply_cell_brightness",
    "cell_brightness_gains",
    "draw_frame",
    "iter_render",
    "iter_scenes",
    "montage",
    "noise_rng",
    "render_simulation",
    "stain_cells",
]

Progress = Callable[[int, int], None]

#: Threads that draw scenes (and their masks) ahead of the renderer in
#: :func:`iter_render`: the compiled drawing kernels release the GIL, so a frame's
#: drawing overlaps the others' and the rendering (at most 8; 1 draws in the caller).
DRAW_THREADS = min(8, os.cpu_count() or 1)


@dataclass(frozen=True)
class RenderedSeries:
    """A rendered time series with its ground truth, all at camera resolution.

    Attributes
    ----------
    images
        ``(T, Y, X)`` uint16 camera images.
    labels
        ``(T, Y, X)`` uint32 instance masks; a value is the simulation's cell id, so
        the same cell keeps its value across frames (tracking ground truth).
    semantic
        ``(T, Y, X)`` uint8 masks, 1 in cells, cells separated by zero pixels (eq. 4-5).
    """

    images: np.ndarray
    labels: np.ndarray
    semantic: np.ndarray

    @classmethod
    def from_frames(cls, frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> RenderedSeries:
        """Stack ``(image, labels, semantic)`` tuples from :func:`iter_render`."""
        if not frames:
            raise ValueError("cannot build a RenderedSeries from zero frames")
        images, labels, semantic = zip(*frames)
        return cls(np.stack(images), np.stack(labels), np.stack(semantic))


def noise_rng(settings: PipelineSettings) -> np.random.Generator:
    """The generator used for rendering noise, derived from the simulation seed.

    It is independent of the simulation's own stream, so re-rendering a saved
    simulation gives the same images as rendering it right after simulating.
    """
    return np.random.default_rng(np.random.SeedSequence([settings.simulation.seed, 1]))


def _curvature(simulation: Simulation) -> dict[int, tuple[float, float, float]] | None:
    curvature = {
        cell_id: record.curvature
        for cell_id, record in simulation.lineage.items()
        if any(record.curvature)
    }
    return curvature or None


def cell_brightness_gains(
    cell_ids: np.ndarray, cv: float, seed: int, max_gain: float = 0.0
) -> np.ndarray:
    """Per-cell brightness gains (section 13.2.2): gamma, mean 1, coefficient of variation ``cv``.

    Each cell's gain comes from its own generator, seeded from ``[seed, 3, cell id]``,
    so it depends only on the seed and the id: a cell keeps its gain in every frame
    (like its expression level over a cell cycle), whatever other cells are present.
    With ``max_gain > 0`` the gamma is truncated there (a cell's generator draws again
    until its gain is at most ``max_gain``): the brightest cells stay within the
    recording's range (ColiCoords ds1 field 5, CV 0.99 from 4 cells: untruncated,
    exported cells were up to 2.4x the brightest real one). A gain the first draw
    keeps is the same as without the bound.
    """
    if not (np.isfinite(cv) and cv >= 0):
        raise ValueError(f"cv must be zero or positive, got {cv!r}")
    if not (max_gain == 0 or (np.isfinite(max_gain) and max_gain >= 1)):
        raise ValueError(
            f"max_gain must be 0 (no bound) or at least 1 (the mean gain), got {max_gain!r}"
        )
    ids = np.asarray(cell_ids, np.int64).ravel()
    if cv == 0:
        return np.ones(ids.size)
    shape = 1.0 / cv**2
    bound = max_gain if max_gain > 0 else np.inf

    def gain(cell_id: int) -> float:
        rng = np.random.default_rng([int(seed), 3, cell_id])
        value = rng.gamma(shape, 1.0 / shape)
        while value > bound:  # a gamma's median is below its mean: kept with p > 1/2
            value = rng.gamma(shape, 1.0 / shape)
        return value

    return np.array([gain(int(cell_id)) for cell_id in ids], np.float64)


def apply_cell_brightness(scene: Scene, cv: float, seed: int, max_gain: float = 0.0) -> Scene:
    """Multiply each cell of ``scene`` by its gain of :func:`cell_brightness_gains`
    (at most ``max_gain`` when it is positive).

    ``cv = 0`` returns ``scene`` itself (no copy, bit-identical rendering). The gains
    scale each cell's material as :func:`~napari_symbac.scene.scale_cells` does (eq. 3
    adds ``g (I_c - I_m)``: a dim cell fades towards the medium, never below it; with
    the share left out a cell of gain near 0 imaged as a rod darker than the
    background, in fluorescence). In phase contrast a gain is the cell's optical path
    relative to the mean cell's, as ``fit_colony`` fits it.
    """
    if cv == 0 or scene.cell_ids.size == 0:
        if not (np.isfinite(cv) and cv >= 0):
            raise ValueError(f"cv must be zero or positive, got {cv!r}")
        return scene
    ids = np.asarray(scene.cell_ids, np.int64)
    return scale_cells(scene, ids, cell_brightness_gains(ids, cv, seed, max_gain))


def stain_cells(scene: Scene, microscope: Microscope, render: RenderSettings) -> Scene:
    """The stain's place in the cells: ``render.envelope_stain_fraction`` of it in the
    envelope (:func:`~napari_symbac.scene.envelope_stain`) in fluorescence, and with
    ``render.depth_layers > 0`` its share in each slab through the depth (eq. 16,
    :func:`~napari_symbac.scene.depth_stain`); phase contrast, which images the optical
    path and not a stain, returns ``scene``."""
    if microscope.modality != "fluorescence":
        return scene
    if render.depth_layers:
        return depth_stain(scene, render.envelope_stain_fraction, render.depth_layers)
    return envelope_stain(scene, render.envelope_stain_fraction)


def _draw(
    simulation: Simulation,
    settings: PipelineSettings,
    index: int,
    curvature: dict[int, tuple[float, float, float]] | None,
    field: Field | None,
) -> Scene:
    scene = draw_scene(
        simulation.frames[index],
        simulation.settings.trench,  # the cells' own (draw_frame says why)
        settings.microscope,
        settings.render,
        curvature=curvature,
        field=field,
    )
    scene = add_media_texture(
        scene,
        settings.render.texture_amplitude,
        simulation.settings.seed,
        settings.render.texture_scale_um,
    )
    scene = stain_cells(scene, settings.microscope, settings.render)
    scene = apply_cell_brightness(
        scene,
        settings.render.cell_brightness_cv,
        simulation.settings.seed,
        settings.render.cell_brightness_max_gain,
    )
    return add_debris(scene, settings.render, debris_rng(simulation.settings.seed))


def draw_frame(simulation: Simulation, settings: PipelineSettings, index: int) -> Scene:
    """Draw the scene of frame ``index`` of ``simulation``, in any geometry.

    A trench or chamber is drawn with the simulation's own trench (``settings.simulation``
    is not used: found as an API user, settings of a 10 um trench cut a 16 um trench's
    frames to 166 px of 258, its lower cells lost); an agar pad or
    an outline in the field of view of :func:`~napari_symbac.scene.field_of`
    ``(simulation)``. With ``settings.render.texture_amplitude > 0`` the media carries
    the Perlin texture of the simulation's seed (:func:`~napari_symbac.scene.add_media_texture`);
    in fluorescence with ``settings.render.envelope_stain_fraction > 0`` that part of the
    stain sits in the cells' envelope (:func:`stain_cells`);
    with ``settings.render.cell_brightness_cv > 0`` each cell has its own brightness
    (:func:`apply_cell_brightness`, the same for a cell in every frame); with
    ``settings.render.debris_density_per_100um2 > 0`` unlabelled out-of-focus particles
    lie on the medium (:func:`~napari_symbac.scene.add_debris`, the same on every frame).
    """
    return _draw(simulation, settings, index, _curvature(simulation), field_of(simulation))


def iter_scenes(simulation: Simulation, settings: PipelineSettings) -> Iterator[Scene]:
    """Draw the scene of every frame of ``simulation`` (as :func:`draw_frame`)."""
    curvature = _curvature(simulation)
    field = field_of(simulation)
    for index in range(len(simulation.frames)):
        yield _draw(simulation, settings, index, curvature, field)


def _drawn_scenes(
    simulation: Simulation, settings: PipelineSettings, threads: int
) -> Iterator[Scene]:
    """The scenes of :func:`iter_scenes`, in order, each with its camera masks made,
    drawn by ``threads`` threads at most ``2 * threads`` frames ahead of the caller."""
    curvature = _curvature(simulation)
    field = field_of(simulation)
    count = len(simulation.frames)

    def draw(index: int) -> Scene:
        scene = _draw(simulation, settings, index, curvature, field)
        scene.camera_labels()  # the masks, made once per scene, in this thread
        return scene

    if threads <= 1 or count < 2:
        yield from map(draw, range(count))
        return
    pool = ThreadPoolExecutor(threads, thread_name_prefix="napari-symbac-draw")
    pending: deque[Future[Scene]] = deque()
    try:
        for index in range(count):
            pending.append(pool.submit(draw, index))
            if len(pending) >= 2 * threads:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _check_render_inputs(
    simulation: Simulation, settings: PipelineSettings, rng: np.random.Generator | None
) -> None:
    """Refuse arguments of the wrong type with a message naming the fix."""
    if not isinstance(simulation, Simulation):
        raise TypeError(
            f"render needs a Simulation, got {type(simulation).__name__}: pass the result "
            "of napari_symbac.sim.simulate(...) or load_simulation(folder)"
        )
    if not isinstance(settings, PipelineSettings):
        raise TypeError(
            f"render needs PipelineSettings, got {type(settings).__name__}: pass "
            "PipelineSettings(...) or load_settings(path, PipelineSettings)"
        )
    if rng is not None and not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"rng must be a numpy.random.Generator, got {type(rng).__name__} {rng!r}: pass "
            "numpy.random.default_rng(seed), or leave it out to seed from the settings"
        )


def iter_render(
    simulation: Simulation,
    settings: PipelineSettings,
    rng: np.random.Generator | None = None,
    *,
    backend: str = "scipy",
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Render a simulation frame by frame.

    Yields ``(image, labels, semantic)`` per frame at camera resolution: the uint16
    image, the uint32 instance mask (values are cell ids) and the uint8 semantic mask.
    ``rng`` drives the noise and defaults to :func:`noise_rng` of ``settings``.
    ``backend`` is a name of :func:`~napari_symbac.optics.batched.resolve_backend`:
    ``"scipy"`` (default, frame by frame on the CPU) or ``"torch"`` (frames rendered
    in batches on a torch device, yielded as each batch finishes; a different noise
    stream, see :mod:`napari_symbac.optics.batched`). The scenes and their masks are
    drawn by :data:`DRAW_THREADS` threads ahead of the renderer; the images are the
    same, bit for bit, as drawing them one by one.
    """
    from napari_symbac.diagnose.stages import drawn_stages
    from napari_symbac.optics.batched import render_scenes

    _check_render_inputs(simulation, settings, rng)
    settings = dataclasses.replace(settings, simulation=simulation.settings)
    rng = noise_rng(settings) if rng is None else rng
    model = ForwardModel(
        settings.microscope,
        settings.render,
        settings.camera,
        extra_stages=drawn_stages(settings),
    )
    scenes = _drawn_scenes(simulation, settings, DRAW_THREADS)
    try:
        for scene, image in render_scenes(model, scenes, rng, backend=backend):
            yield image, scene.camera_labels(), scene.semantic_mask()
    finally:
        scenes.close()  # a caller that stops early stops the drawing threads now


def render_simulation(
    simulation: Simulation,
    settings: PipelineSettings,
    rng: np.random.Generator | None = None,
    progress: Progress | None = None,
    *,
    backend: str = "scipy",
) -> RenderedSeries:
    """Render every frame of a simulation with its masks.

    Parameters
    ----------
    simulation
        Output of :func:`napari_symbac.sim.simulate` or :func:`~napari_symbac.sim.load_simulation`.
    settings
        Microscope, render and camera settings (its ``simulation`` part is not used:
        the simulation's own settings are, its trench and its seed).
    rng
        Generator for the noise; defaults to :func:`noise_rng` of ``settings`` with the
        simulation's own settings.
    progress
        Called as ``progress(done, total)`` after each frame.
    backend
        ``"scipy"`` (default), ``"torch"`` (batched on cuda when available, else cpu),
        ``"torch:cpu"``, ``"torch:cuda"`` or ``"cupy"`` (see :func:`iter_render`).
    """
    _check_render_inputs(simulation, settings, rng)
    frames = []
    total = len(simulation.frames)
    for frame in iter_render(simulation, settings, rng, backend=backend):
        frames.append(frame)
        if progress is not None:
            progress(len(frames), total)
    return RenderedSeries.from_frames(frames)


def montage(
    images: np.ndarray, labels: np.ndarray | None = None, *, columns: int = 12
) -> np.ndarray:
    """Tile frames side by side into an 8-bit RGB preview, mask outlines in yellow.

    Parameters
    ----------
    images
        ``(T, Y, X)`` images; contrast is stretched to the 0.5-99.5 percentiles.
    labels
        Optional ``(T, Y, X)`` instance masks whose boundaries are drawn over the images.
    columns
        Frames per row of the montage.
    """
    from skimage.segmentation import find_boundaries

    images = np.asarray(images, dtype=np.float32)
    if images.ndim != 3:
        raise ValueError(f"montage expects a (T, Y, X) stack, got shape {images.shape}")
    low, high = np.percentile(images, [0.5, 99.5])
    grey = np.clip((images - low) / max(high - low, 1e-6), 0, 1)
    rgb = np.repeat((grey * 255).astype(np.uint8)[..., None], 3, axis=-1)
    if labels is not None:
        edges = np.stack([find_boundaries(frame, mode="inner") for frame in labels])
        rgb[edges] = (255, 220, 0)
    t, y, x = grey.shape
    columns = max(1, min(columns, t))
    rows = -(-t // columns)
    gap = 2
    canvas = np.zeros((rows * (y + gap) - gap, columns * (x + gap) - gap, 3), np.uint8)
    for i in range(t):
        r, c = divmod(i, columns)
        canvas[r * (y + gap) : r * (y + gap) + y, c * (x + gap) : c * (x + gap) + x] = rgb[i]
    return canvas
