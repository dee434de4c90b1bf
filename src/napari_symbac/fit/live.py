"""Live tuning: re-render a frame after each parameter change, from cached convolutions.

This is the headless engine behind the napari tuning sliders. A change of an
intensity or of the noise recombines the cached per-component convolutions of the
:class:`~napari_symbac.optics.ForwardModel`; a change of a PSF parameter convolves the
current frame once and caches it too.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from napari_symbac.optics import ForwardModel
from napari_symbac.optics.matching import match_fourier_spectrum, match_histogram
from napari_symbac.settings import Camera, Microscope, RenderSettings

__all__ = ["LivePreview"]

_MICROSCOPE_FIELDS = {f.name for f in dataclasses.fields(Microscope)}
_RENDER_FIELDS = {f.name for f in dataclasses.fields(RenderSettings)}
_CAMERA_FIELDS = {f.name for f in dataclasses.fields(Camera)}


class LivePreview:
    """Renders frames of a fixed set of scenes under changing parameters.

    Parameters
    ----------
    scenes
        The scenes (one per frame), or a callable ``scene(index)`` that draws them on
        demand; drawn scenes are kept so a frame is drawn once.
    n_frames
        Number of frames when ``scenes`` is a callable.
    microscope, render, camera
        Starting parameters.
    seed
        Seed of the noise. Frame ``t`` always gets the generator
        ``default_rng([seed, t])``, so the noise does not flicker while a slider moves.
    """

    def __init__(
        self,
        scenes: Sequence[Any] | Callable[[int], Any],
        microscope: Microscope,
        render: RenderSettings,
        camera: Camera,
        *,
        n_frames: int | None = None,
        seed: int = 0,
    ) -> None:
        if callable(scenes):
            if n_frames is None:
                raise ValueError("n_frames is required when scenes is a callable")
            self._draw = scenes
            self._scenes: dict[int, Any] = {}
            self.n_frames = n_frames
        else:
            self._scenes = dict(enumerate(scenes))
            self._draw = self._scenes.__getitem__
            self.n_frames = len(self._scenes)
        if self.n_frames < 1:
            raise ValueError("LivePreview needs at least one scene")
        self.model = ForwardModel(microscope, render, camera)
        self.seed = seed
        self.reference: np.ndarray | None = None
        self.match_fourier = False
        self.match_histogram = False

    @property
    def render_settings(self) -> RenderSettings:
        """The render settings now in force."""
        return self.model.render_settings

    def scene(self, index: int) -> Any:
        """The scene of frame ``index`` (drawn on first use)."""
        if not 0 <= index < self.n_frames:
            raise IndexError(f"frame {index} is outside 0..{self.n_frames - 1}")
        if index not in self._scenes:
            self._scenes[index] = self._draw(index)
        return self._scenes[index]

    def update(self, **changes: Any) -> None:
        """Change parameters of the microscope, render settings or camera by name.

        Raises
        ------
        ValueError
            For an unknown name or an impossible value (the settings' own message);
            the previous parameters stay in force.
        """
        unknown = set(changes) - _MICROSCOPE_FIELDS - _RENDER_FIELDS - _CAMERA_FIELDS
        if unknown:
            raise ValueError(f"unknown parameter(s) {', '.join(sorted(unknown))}")
        model = self.model
        micro = {k: v for k, v in changes.items() if k in _MICROSCOPE_FIELDS}
        render = {k: v for k, v in changes.items() if k in _RENDER_FIELDS}
        camera = {k: v for k, v in changes.items() if k in _CAMERA_FIELDS}
        if micro:
            model = model.with_microscope(dataclasses.replace(model.microscope, **micro))
        if render:
            model = model.with_render(dataclasses.replace(model.render_settings, **render))
        elif micro:  # re-check the render settings against the new microscope (eq. 13)
            model = model.with_render(model.render_settings)
        if camera:
            model = model.with_camera(dataclasses.replace(model.camera, **camera))
        self.model = model

    def set_reference(
        self, image: np.ndarray | None, *, fourier: bool = False, histogram: bool = False
    ) -> None:
        """Match rendered frames to a real ``image`` (2D) by spectrum and/or histogram."""
        if image is not None:
            image = np.asarray(image, dtype=np.float32)
            if image.ndim != 2:
                raise ValueError(f"the reference must be one 2D frame, got shape {image.shape}")
        self.reference = image
        self.match_fourier = fourier and image is not None
        self.match_histogram = histogram and image is not None

    def frame(self, index: int) -> np.ndarray:
        """Render frame ``index`` with the current parameters (float32, camera pixels)."""
        scene = self.scene(index)
        rng = np.random.default_rng([self.seed, index])
        image = self.model.render(scene, rng).astype(np.float32)
        if self.reference is not None and (self.match_fourier or self.match_histogram):
            reference = self.reference
            if reference.shape != image.shape:
                raise ValueError(
                    f"the reference image {reference.shape} and the rendered frame "
                    f"{image.shape} differ in shape: crop the real image to the trench"
                )
            if self.match_fourier:
                image = match_fourier_spectrum(image, reference).astype(np.float32)
            if self.match_histogram:
                image = match_histogram(image, reference).astype(np.float32)
        return image
