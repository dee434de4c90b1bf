"""What every effect of the catalogue provides."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from napari_symbac.diagnose.model import Geometry
from napari_symbac.optics.forward import Stage, block_average

__all__ = ["CellPatternEffect", "Confirmation", "Effect", "gaussian"]


def gaussian(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur of each frame of a ``(T, Y, X)`` stack (reflecting edges)."""
    from scipy import ndimage

    return ndimage.gaussian_filter(image, (0, sigma_px, sigma_px), mode="reflect")


@dataclass(frozen=True, eq=False)
class Confirmation:
    """An effect's own check of its fit, beyond the held-out pixels (:meth:`Effect.confirm`).

    Attributes
    ----------
    confirmed
        Whether the fitted effect looks like the physics it names.
    reason
        Why, in a sentence for the report (empty when the effect has no check).
    numbers
        The measured quantities behind it (units in the names), for diagnosis.json.
    """

    confirmed: bool
    reason: str = ""
    numbers: Mapping[str, float] = field(default_factory=dict)


class Effect:
    """A physical effect the base model leaves out.

    Subclasses set the class attributes and implement :meth:`mean` (effects on the
    mean image), or set ``kind`` to ``"variance"`` / ``"censor"``. The stage that
    carries a fitted effect into rendering is in its module (``stage(parameters)``)
    or a settings field (:mod:`napari_symbac.diagnose.stages`).

    Attributes
    ----------
    name
        Identifier (module name).
    explanation
        What it is, in a microscopist's words.
    signature
        Where it shows in the discrepancy statistics.
    kind
        ``"mean"``, ``"variance"`` or ``"censor"``.
    needs_series
        Only testable on a time series.
    modalities
        Modalities where the effect applies.
    random_field
        The parameters are many small exchangeable draws (a texture's modes): fitted
        by empirical Bayes, shrunk towards 0 as much as the data's own score says
        (``model.fit_model``), instead of freely.
    """

    name: ClassVar[str] = ""
    explanation: ClassVar[str] = ""
    signature: ClassVar[str] = ""
    kind: ClassVar[str] = "mean"
    needs_series: ClassVar[bool] = False
    modalities: ClassVar[tuple[str, ...]] = ("phase", "fluorescence", "brightfield")
    random_field: ClassVar[bool] = False

    def __init__(self, geometry: Geometry) -> None:
        self.geometry = geometry

    # ------------------------------------------------------------------ model
    def n_params(self) -> int:
        """Number of parameters (may depend on the geometry: per cell, per column)."""
        raise NotImplementedError

    def mean(
        self, theta: np.ndarray, mu: np.ndarray, parts: np.ndarray, geo: Geometry
    ) -> np.ndarray:
        """The mean image with the effect applied; ``theta = 0`` returns ``mu``.

        ``parts`` is ``(3, T, Y, X)``: the cells, media and device contributions
        (intensity times convolved component) of the base model.
        """
        return mu

    def null(self) -> np.ndarray:
        """Parameters of "no effect"."""
        return np.zeros(self.n_params())

    def steps(self, theta: np.ndarray) -> np.ndarray:
        """Finite-difference steps (the effect is linear or nearly so in its parameters)."""
        return np.full(len(theta), 1e-3)

    def clip(self, theta: np.ndarray) -> np.ndarray:
        """Keep parameters in their physical range."""
        return theta

    def confirm(
        self,
        theta: np.ndarray,
        residual_adu: np.ndarray,
        valid: np.ndarray,
        mean_adu: np.ndarray,
    ) -> Confirmation:
        """Whether the fitted effect is the physics it names (the last condition of
        acceptance, after the score test and the held-out check).

        A flexible effect can gain on the held-out pixels by absorbing another misfit;
        an effect with a physical check of its own overrides this: a camera's column
        offsets (``fixed_pattern_noise``) and the light's surface
        (``uneven_illumination``) act far from the cells too, and must fit there
        (:mod:`~napari_symbac.diagnose.effects.far_from_cells`). The default has none.

        Parameters
        ----------
        theta
            The effect's fitted parameters (mean effects; as they act in the fitted mean).
        residual_adu
            ``(T, Y, X)`` data minus the fitted mean of the model with the effect (ADU).
        valid
            ``(T, Y, X)`` pixels the fit used.
        mean_adu
            ``(T, Y, X)`` that fitted mean (ADU above the baseline), the effect applied
            last (as the diagnosis fits a candidate).
        """
        return Confirmation(True)

    # ------------------------------------------------------------------ report
    def summary(self, theta: np.ndarray, mu: np.ndarray) -> dict[str, Any]:
        """Plain, named parameters for diagnosis.json (units in the names)."""
        return {f"theta_{k}": float(v) for k, v in enumerate(theta)}

    def magnitude(self, summary: dict[str, Any]) -> float:
        """The one number the benchmark compares with the truth."""
        return float(next(iter(summary.values())))

    # ------------------------------------------------------------------ benchmark
    def direction(self, rng: np.random.Generator) -> np.ndarray:
        """A random parameter direction for the concealed-effect generator."""
        return rng.normal(size=self.n_params())



class CellPatternEffect(Effect):
    """An effect that adds ``a P`` to the mean: one amplitude ``a`` (ADU) times a
    pattern ``P`` drawn from the cells' mask (a ring, a haze, ...).

    Subclasses set :attr:`pattern`, ``pattern(cell_fraction, pixel_size_um)`` on a
    ``(T, Y, X)`` stack. Its scale is fixed (:attr:`amplitude_at` says where it is 1),
    never the image's own peak: the same amplitude then draws the same effect in the
    fitted recording, in each frame of an export and in a frame of one cell (a haze
    scaled to each frame's peak drew a lone cell's surroundings as dark as a full
    trench's).
    """

    pattern: ClassVar[Callable[[np.ndarray, float], np.ndarray]]
    #: Where the pattern is 1, in words for the report: the amplitude's meaning.
    amplitude_at: ClassVar[str] = ""
    #: What a positive and a negative amplitude mean, in words (the report says which
    #: the fit found; found as a user: "halo -173 ADU" left the sign to decode).
    sign_words: ClassVar[tuple[str, str]] = ("", "")

    @classmethod
    def finding(cls, parameters: dict) -> str:
        """The fitted amplitude in words: :attr:`sign_words` by its sign, and its size."""
        amplitude = float(parameters["amplitude_adu"])
        words = cls.sign_words[0] if amplitude > 0 else cls.sign_words[1]
        return f"{words} ({amplitude:+.3g} ADU {cls.amplitude_at})" if words else ""

    def __init__(self, geometry: Geometry) -> None:
        super().__init__(geometry)
        self._pattern = type(self).pattern(geometry.cell_fraction, geometry.pixel_size_um)

    def n_params(self) -> int:
        return 1

    def steps(self, theta: np.ndarray) -> np.ndarray:
        return np.ones(1)

    def mean(
        self, theta: np.ndarray, mu: np.ndarray, parts: np.ndarray, geo: Geometry
    ) -> np.ndarray:
        return mu + theta[0] * self._pattern

    def summary(self, theta: np.ndarray, mu: np.ndarray) -> dict[str, Any]:
        return {"amplitude_adu": float(theta[0])}

    @classmethod
    def stage(cls, parameters: dict) -> Stage:
        """Forward-model stage adding the fitted pattern around the scene's cells."""
        amplitude = float(parameters["amplitude_adu"])

        def apply(image: np.ndarray, scene: Any) -> np.ndarray:
            fraction = block_average(scene.interior(scene.cells), scene.upsample)[None]
            px = scene.pixel_size_um * scene.upsample
            return image + np.float32(amplitude) * cls.pattern(fraction, px)[0].astype(
                np.float32
            )

        return Stage(cls.name, False, dict(parameters), apply)
