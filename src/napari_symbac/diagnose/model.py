"""The model that diagnosis criticises: the base fit, linearised, plus effect stages.

The base fit (:func:`~napari_symbac.fit.fit_scene` or any other) supplies a scene per
frame and the forward-model settings. From them this module builds, at camera
resolution, everything the tests need:

* the *nuisance design*: the convolved cells / media / device components (eq. 3: the
  intensities are linear coefficients) and the derivatives of the rendered image with
  respect to a few optics parameters (central finite differences, one pair of renders
  each), so the nuisance parameters can be re-fitted by weighted least squares on any
  subset of pixels (held-out checks) without re-running the base fit;
* the camera variance of eq. 17, ``v = g s mu + h (s sigma_d)^2 + 1/12`` (``g = h = 1``
  for the declared camera);
* :class:`Geometry`: the scene's cell fraction and labels at camera resolution, the
  signed distance to the nearest cell edge and normalised coordinates;
* :func:`fit_model`: iteratively reweighted Gauss-Newton of the nuisance parameters and
  of the parameters of any effects (:class:`~napari_symbac.diagnose.effects.Effect`)
  on a pixel mask, with the variance held fixed inside each weighted solve and updated
  between rounds (a variance that moves inside the solve biases the background, see
  ``diagnosis-notes.md``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import ndimage, special

from napari_symbac.arguments import require_argument
from napari_symbac.optics.forward import ForwardModel, block_average
from napari_symbac.pipeline import stain_cells
from napari_symbac.scene import Scene
from napari_symbac.settings import Camera, Microscope, RenderSettings

if TYPE_CHECKING:
    from napari_symbac.diagnose.effects.base import Effect

__all__ = [
    "NUISANCE_OPTICS",
    "BaseDesign",
    "FittedModel",
    "Geometry",
    "build_design",
    "deviance",
    "fit_model",
    "variance",
]

#: Optics parameters re-fitted (linearised) as nuisance; step of the finite difference.
NUISANCE_OPTICS: dict[str, dict[str, float]] = {
    "phase": {"defocus_sigma_um": 0.02, "apodisation_sigma_um": 0.05, "psf_offset": 0.01},
    "fluorescence": {"defocus_sigma_um": 0.02},
    "brightfield": {"defocus_sigma_um": 0.02},
}


@dataclass(frozen=True, eq=False)
class Geometry:
    """Camera-resolution geometry of the fitted scene(s), ``(T, Y, X)`` arrays.

    Attributes
    ----------
    cell_fraction
        Block average of the scene's cell material fraction (before the PSF).
    labels
        Instance mask (cell ids, 0 = none).
    distance_px
        Signed distance to the nearest cell edge in pixels (negative inside cells).
    nearest
        Id of the nearest cell (0 where no cell is within ``region_px``).
    xn, yn
        Column and row coordinates scaled to ``[-1, 1]`` (``(Y, X)``).
    t
        Frame index minus its mean (``(T,)``).
    pixel_size_um
        Camera pixel size in the sample.
    modality
        ``"phase"``, ``"fluorescence"`` or ``"brightfield"``.
    media_fraction
        ``(T, Y, X)`` media contribution of the base model per unit media intensity,
        scaled to 1 in open media (``None`` when built from labels alone).
    media_per_cell
        Media over cell intensity of the base settings (``I_m / I_c``, eq. 3): a cell
        that moves leaves media where it was (``cells + media + device = 1``), so the
        image changes by the cells' part times ``1 - I_m / I_c``.
    cell_components
        ``(n_cells, T, Y, X)``: each cell's own convolved contribution at unit cell
        intensity, in the order of :attr:`cell_ids` (the cells' component is their
        sum; ``None`` when built from labels alone). In phase contrast a cell's
        image reaches far beyond its outline (the ring's halo), and neighbours'
        images overlap, so a per-cell brightness needs these, not a mask.
    texture_components
        ``(K, T, Y, X)``: the convolved media component with the media multiplied by
        each texture mode of ``background_texture`` (before the PSF), at unit media
        intensity (``None`` when built from labels alone). The media's texture passes
        through the optics: in phase contrast the kernel's ring filters it, so its
        image is not the mode times the convolved media.
    media_probe
        Flat index of the pixel where the convolved media component is largest, and
        its value there: the fitted media intensity is the media part over it (eq. 3).
    envelope_component
        ``(T, Y, X)``: the convolved cells component with all of the stain in the
        cells' envelope (:func:`~napari_symbac.scene.envelope_stain`) less the
        component with the stain filling them, at unit cell intensity (fluorescence;
        ``None`` in phase contrast or when built from labels alone).
    envelope_fraction
        The fraction of the stain in the envelope that the base model draws
        (``RenderSettings.envelope_stain_fraction``, fluorescence; 0 otherwise).
    """

    cell_fraction: np.ndarray
    labels: np.ndarray
    distance_px: np.ndarray
    nearest: np.ndarray
    xn: np.ndarray
    yn: np.ndarray
    t: np.ndarray
    pixel_size_um: float
    modality: str
    media_fraction: np.ndarray | None = None
    media_per_cell: float = 0.0
    cell_components: np.ndarray | None = None
    texture_components: np.ndarray | None = None
    media_probe: tuple[int, float] = (0, 0.0)
    envelope_component: np.ndarray | None = None
    envelope_fraction: float = 0.0

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.labels.shape  # type: ignore[return-value]

    @property
    def cell_ids(self) -> np.ndarray:
        ids = np.unique(self.labels)
        return ids[ids > 0]


def geometry_from_labels(
    labels: np.ndarray,
    cell_fraction: np.ndarray,
    pixel_size_um: float,
    modality: str,
    region_px: float = 4.0,
) -> Geometry:
    """:class:`Geometry` from ``(T, Y, X)`` camera labels and cell fractions."""
    labels = np.asarray(labels).astype(np.int64)
    n_t, rows, cols = labels.shape
    distance = np.zeros(labels.shape, np.float32)
    nearest = np.zeros(labels.shape, np.int64)
    for k in range(n_t):
        inside = labels[k] > 0
        if inside.any():
            out_d, (iy, ix) = ndimage.distance_transform_edt(~inside, return_indices=True)
            in_d = ndimage.distance_transform_edt(inside)
            distance[k] = np.where(inside, -in_d + 0.5, out_d - 0.5)
            near = labels[k][iy, ix]
            nearest[k] = np.where(out_d <= region_px, near, 0)
        else:
            distance[k] = 1e3
    yn = np.broadcast_to(np.linspace(-1, 1, rows)[:, None], (rows, cols))
    xn = np.broadcast_to(np.linspace(-1, 1, cols)[None, :], (rows, cols))
    t = np.arange(n_t, dtype=float)
    return Geometry(
        cell_fraction=np.asarray(cell_fraction, np.float64),
        labels=labels,
        distance_px=distance,
        nearest=nearest,
        xn=xn,
        yn=yn,
        t=t - t.mean(),
        pixel_size_um=float(pixel_size_um),
        modality=modality,
    )


@dataclass(frozen=True, eq=False)
class BaseDesign:
    """Nuisance design of the base model (all arrays ``(T, Y, X)``).

    Attributes
    ----------
    components
        ``(3, T, Y, X)``: convolved cells, media, device at unit intensity (eq. 3, 15).
        The effects act on these classes' parts (``beta[:3]`` times them).
    optics
        ``(k, T, Y, X)``: derivative of the rendered image with respect to each of
        ``optics_names`` (ADU per unit), at the fitted intensities.
    optics_names
        Names of the optics nuisance parameters (:data:`NUISANCE_OPTICS`).
    intensities
        The base fit's ``(I_cells, I_media, I_device)``.
    camera
        The declared camera.
    geometry
        :class:`Geometry` of the scene(s).
    lens
        Bright field: ``(T, Y, X)``, minus the cells through the lens kernel
        (:meth:`~napari_symbac.optics.forward.ForwardModel.ring_kernel`), the column of
        the cells' lens term out of focus, a linear amplitude ``kappa I_m`` (ADU um^2,
        docs/physics.md "Bright field") re-fitted with the intensities, after them in
        ``beta``; ``None`` in phase contrast and fluorescence.
    lens_amplitude
        The base fit's ``kappa I_m`` (0 without a lens column).
    """

    components: np.ndarray
    optics: np.ndarray
    optics_names: tuple[str, ...]
    intensities: np.ndarray
    camera: Camera
    geometry: Geometry
    lens: np.ndarray | None = None
    lens_amplitude: float = 0.0

    @property
    def n_linear(self) -> int:
        """Linear coefficients first in ``beta``: the intensities and the lens amplitude."""
        return 3 + (self.lens is not None)

    @property
    def n_nuisance(self) -> int:
        return self.n_linear + len(self.optics_names)

    def columns(self) -> np.ndarray:
        """``(p, T, Y, X)``: all nuisance columns."""
        lens = () if self.lens is None else (self.lens[None],)
        return np.concatenate([self.components, *lens, self.optics], axis=0)

    def start(self) -> np.ndarray:
        """Nuisance coefficients of the base fit (intensities, the lens amplitude, no
        optics change)."""
        lens = [self.lens_amplitude] if self.lens is not None else []
        return np.concatenate([self.intensities, lens, np.zeros(len(self.optics_names))])


def build_design(
    scenes: Sequence[Any],
    microscope: Microscope,
    render: RenderSettings,
    camera: Camera,
    *,
    optics: Sequence[str] | None = None,
) -> BaseDesign:
    """The nuisance design from fitted scenes (one per frame) and forward-model settings.

    Needs nothing else from the base fit: the intensities are re-fitted linearly and
    the optics parameters in ``optics`` (default :data:`NUISANCE_OPTICS`) by one
    linearisation (central differences of two renders each). The scenes are drawn
    as the pipeline draws them (part of a fluorescence stain in the cells' envelope
    when ``render`` says so: :func:`~napari_symbac.pipeline.stain_cells`).

    Parameters
    ----------
    scenes
        One fitted scene per frame (``[fit.scene]`` for one frame).
    microscope, render, camera
        The forward model the scenes were fitted with (``fit.render``, ``fit.camera``).
    optics
        Optics parameters linearised as nuisances.

    Raises
    ------
    TypeError
        One scene instead of a list, or settings of the wrong kind.
    """
    if isinstance(scenes, Scene):
        raise TypeError("build_design takes one scene per frame, a list: pass [scene]")
    require_argument(microscope, Microscope, "build_design(microscope=...)")
    require_argument(render, RenderSettings, "build_design(render=...)")
    require_argument(camera, Camera, "build_design(camera=...)")
    if not scenes:
        raise ValueError("build_design needs at least one scene")
    names = tuple(NUISANCE_OPTICS[microscope.modality] if optics is None else optics)
    model = ForwardModel(microscope, render, camera)
    intensities = np.array(
        [render.cell_intensity, render.media_intensity, render.device_intensity], float
    )
    brightfield = microscope.modality == "brightfield"
    comps, lenses, derivs, fractions, labels, scene_list = [], [], [], [], [], []
    for raw in scenes:
        scene = stain_cells(raw, microscope, render)  # the stain as the settings draw it
        scene_list.append(scene)
        parts = model.components(scene)
        comps.append(np.stack([parts[c] for c in ("cells", "media", "device")]))
        if brightfield:  # subtracted with weight kappa I_m (ForwardModel.ring_amplitudes)
            lenses.append(-np.asarray(parts["cells_phase"], np.float64))
        frame_derivs = []
        for name in names:
            step = NUISANCE_OPTICS.get(microscope.modality, {}).get(name, 0.02)
            value = getattr(render, name)
            lo = max(value - step, 1e-6) if name != "psf_offset" else value - step
            if name == "apodisation_sigma_um":
                lo = max(lo, microscope.min_apodisation_sigma_um)
            hi = value + step
            up = model.with_render(dataclasses.replace(render, **{name: hi}))
            down = model.with_render(dataclasses.replace(render, **{name: lo}))
            frame_derivs.append(
                (up.render_clean(scene) - down.render_clean(scene)).astype(np.float64) / (hi - lo)
            )
        derivs.append(
            np.stack(frame_derivs) if frame_derivs else np.zeros((0, *parts["cells"].shape))
        )
        fractions.append(block_average(raw.interior(raw.cells), raw.upsample))
        labels.append(scene.camera_labels())
    components = np.stack(comps, axis=1).astype(np.float64)
    optics_cols = np.stack(derivs, axis=1) if names else np.zeros((0, *components.shape[1:]))
    geometry = geometry_from_labels(
        np.stack(labels), np.stack(fractions), microscope.pixel_size_um, microscope.modality
    )
    media = np.abs(components[1])
    top = float(np.percentile(media, 99)) if media.size else 0.0
    geometry = dataclasses.replace(
        geometry,
        media_fraction=np.clip(media / top, 0.0, 1.0) if top > 0 else None,
        media_per_cell=float(intensities[1] / intensities[0]) if intensities[0] != 0 else 0.0,
    )
    geometry = dataclasses.replace(
        geometry,
        cell_components=_cell_components(model, scene_list, geometry.cell_ids),
        texture_components=_texture_components(model, scene_list, geometry),
        envelope_component=_envelope_component(model, scenes)
        if microscope.modality == "fluorescence"
        else None,
        envelope_fraction=render.envelope_stain_fraction
        if microscope.modality == "fluorescence"
        else 0.0,
        media_probe=(int(np.argmax(media)), float(components[1].ravel()[np.argmax(media)]))
        if media.size
        else (0, 0.0),
    )
    return BaseDesign(
        components,
        optics_cols,
        names,
        intensities,
        camera,
        geometry,
        lens=np.stack(lenses) if brightfield else None,
        lens_amplitude=model.ring_amplitudes()[0] if brightfield else 0.0,
    )


def _texture_components(
    model: ForwardModel, scenes: Sequence[Any], geometry: Geometry
) -> np.ndarray:
    """``(K, T, Y, X)``: the convolved media with the media times each texture mode."""
    from napari_symbac.diagnose.effects.background_texture import texture_modes

    modes = texture_modes(geometry)
    out = np.zeros((len(modes), *geometry.shape))
    for t, scene in enumerate(scenes):
        rows, cols = geometry.shape[1:]
        u, b = scene.upsample, scene.border_px
        # the camera pixel coordinate of each render pixel, continued into the border
        y = (np.arange(scene.shape[0]) - b + 0.5) / u / rows
        x = (np.arange(scene.shape[1]) - b + 0.5) / u / cols
        for k, (ky, kx) in enumerate(modes):
            mode = np.cos(np.pi * ky * y)[:, None] * np.cos(np.pi * kx * x)[None, :]
            textured = scene.replace_media((scene.media * mode).astype(np.float32))
            out[k, t] = model.components(textured)["media"]
    return out


def _envelope_component(model: ForwardModel, scenes: Sequence[Any]) -> np.ndarray:
    """``(T, Y, X)``: the convolved cells with their stain in the envelope less the
    convolved cells with it filling them (eq. OPL2 and its shell), unit intensity."""
    from napari_symbac.scene import envelope_stain

    frames = []
    for scene in scenes:
        shift = envelope_stain(scene, 1.0).cells - scene.cells
        frames.append(model.components(scene.replace_cells(shift))["cells"])
    return np.stack(frames).astype(np.float64)


def _cell_components(model: ForwardModel, scenes: Sequence[Any], ids: np.ndarray) -> np.ndarray:
    """``(n_cells, T, Y, X)``: the convolved cells component of each cell alone (eq. 3)."""
    out = []
    for cell_id in ids:
        frames = []
        for scene in scenes:
            alone = scene.replace_cells(scene.cells * (scene.labels == cell_id))
            frames.append(np.asarray(model.components(alone)["cells"], np.float64))
        out.append(np.stack(frames))
    if not out:
        return np.zeros((0, len(scenes), *model.components(scenes[0])["cells"].shape))
    return np.stack(out)


def variance(mu: np.ndarray, camera: Camera, gain: float = 1.0, read: float = 1.0) -> np.ndarray:
    """Camera variance of eq. 17 in ADU^2 with optional gain / read-noise factors."""
    s = camera.sensitivity_adu_per_e
    return gain * s * np.maximum(mu, 0.0) + read * (s * camera.dark_noise_e) ** 2 + 1.0 / 12.0


@dataclass(frozen=True, eq=False)
class Censor:
    """Pixels at or beyond ``level_adu`` (above the baseline) were clipped there."""

    level_adu: float
    high: bool = True

    def mask(self, y: np.ndarray) -> np.ndarray:
        return y >= self.level_adu - 0.5 if self.high else y <= self.level_adu + 0.5

    def clip_z(self, mu: np.ndarray, var: np.ndarray) -> np.ndarray:
        """How far the clip (half a grey level out) lies from ``mu`` towards the clipped
        side, in s.d.: ``Y ~ N(mu, var)`` is clipped with probability ``Phi(-z)``."""
        if self.high:
            return (self.level_adu - 0.5 - mu) / np.sqrt(var)
        return -(self.level_adu + 0.5 - mu) / np.sqrt(var)

    def standardised_mean(self, mu: np.ndarray, var: np.ndarray) -> np.ndarray:
        """``E[(Y - mu) / sd | Y clipped]`` for ``Y ~ N(mu, var)``: the censored pixel's
        expected standardised residual (Chesher and Irish's generalised residual of a
        censored normal model), ``phi(z) / Phi(-z)`` (:meth:`clip_z`), above a ceiling
        and negated below a floor."""
        z = self.clip_z(mu, var)
        ratio = np.exp(-0.5 * z**2 - 0.5 * math.log(2 * math.pi) - special.log_ndtr(-z))
        return ratio if self.high else -ratio


@dataclass(frozen=True, eq=False)
class FittedModel:
    """A fitted model: nuisance coefficients, effects with parameters, camera factors."""

    beta: np.ndarray
    effects: tuple[tuple[Effect, np.ndarray], ...]
    gain: float = 1.0
    read: float = 1.0
    censor: Censor | None = None
    mu: np.ndarray = field(default=None, repr=False)  # type: ignore[assignment]
    var: np.ndarray = field(default=None, repr=False)  # type: ignore[assignment]
    #: per effect, the empirical-Bayes shrinkage ``tau^2 / (1 + tau^2)`` of a random
    #: field (1 for the others): the fitted field is the free fit times it
    shrinkage: tuple[float, ...] = ()


def predict(
    design: BaseDesign, beta: np.ndarray, effects: Sequence[tuple[Effect, np.ndarray]]
) -> np.ndarray:
    """Mean image of the base model with coefficients ``beta`` and the effects applied."""
    mu, parts = base_mean(design, beta)
    return apply_effects(mu, effects, parts, design)


def weighted_sum(weights: np.ndarray, stack: np.ndarray) -> np.ndarray:
    """``sum_k weights[k] stack[k]``.

    The arithmetic of ``np.tensordot(weights, stack, axes=1)`` (one matrix product,
    the same numbers) without its Python overhead, which a diagnosis pays a few
    hundred thousand times.
    """
    w = np.asarray(weights)
    return np.dot(w.reshape(1, -1), stack.reshape(len(w), -1)).reshape(stack.shape[1:])


def base_mean(design: BaseDesign, beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The base model's mean image and its per-class parts (what the effects act on)."""
    mu = weighted_sum(beta, design.columns())
    return mu, beta[:3, None, None, None] * design.components


def apply_effects(
    mu: np.ndarray,
    effects: Sequence[tuple[Effect, np.ndarray]],
    parts: np.ndarray,
    design: BaseDesign,
) -> np.ndarray:
    """``mu`` passed through ``effects`` in turn (the chain of :func:`predict`).

    A finite difference in one effect's parameters re-applies only that effect and
    those after it to the mean before it: the same operations as :func:`predict`, so
    the same numbers, without re-rendering the base model and the earlier effects.
    """
    for effect, theta in effects:
        mu = effect.mean(np.asarray(theta, float), mu, parts, design.geometry)
    return mu


def _jacobian(design: BaseDesign, beta: np.ndarray, effects: list, mu: np.ndarray) -> np.ndarray:
    cols = [design.columns()[j] for j in range(len(beta))]
    if effects:
        # the chain is affine in beta for the catalogue's effects: exact differences
        cols = []
        for j in range(len(beta)):
            b = beta.copy()
            b[j] += 1.0
            cols.append(predict(design, b, effects) - mu)
    before, parts = base_mean(design, beta)  # the mean entering effect i
    for i, (effect, theta) in enumerate(effects):
        steps = effect.steps(theta)
        after = effects[i + 1 :]
        for k in range(len(theta)):
            tu, td = np.array(theta, float), np.array(theta, float)
            tu[k] += steps[k]
            td[k] -= steps[k]
            up = apply_effects(before, [(effect, tu), *after], parts, design)
            down = apply_effects(before, [(effect, td), *after], parts, design)
            cols.append((up - down) / (2 * steps[k]))
        before = apply_effects(before, [(effect, theta)], parts, design)
    return np.stack(cols) if cols else np.zeros((0, *mu.shape))


#: Levenberg-Marquardt damping tried, in turn, when the Gauss-Newton step does not
#: lower the weighted cost (on the normal matrix scaled to a unit diagonal).
DAMPING = (1e-6, 1e-4, 1e-2, 1.0, 1e2, 1e4)


def _trial(design, beta, effects, step):
    trial_effects, pos = [], len(beta)
    for e, theta in effects:
        trial_effects.append((e, e.clip(theta + step[pos : pos + len(theta)])))
        pos += len(theta)
    trial_beta = beta + step[: len(beta)]
    return trial_beta, trial_effects, predict(design, trial_beta, trial_effects)


def _params_vector(beta, effects) -> np.ndarray:
    return np.concatenate([beta, *[np.asarray(t, float) for _, t in effects]])


def _descent_step(design, beta, effects, normal, rhs, mu, yv, idx, w, cost, penalty=None):
    """``(beta, effects, mu)`` after a step that lowers the weighted cost ``cost``.

    ``penalty`` (a precision matrix over all parameters, or ``None``) adds
    ``p^T penalty p`` to the cost; ``normal`` and ``rhs`` must include it.

    The Gauss-Newton step first (it does for the catalogue's linear effects, so their
    fits are unchanged); else Levenberg-Marquardt steps of growing damping; else the
    parameters stay. Nearly collinear parameters (a texture's column modes beside
    per-column offsets, with a finite-difference Jacobian) make the undamped step wild
    in their common direction: on a background-subtracted ColiCoords field it sent
    the mean to overflow and the diagnosis ended in "SVD did not converge".
    """
    diagonal = np.diag(normal)
    # A parameter nothing depends on (an open field's device: its column is 0) does not
    # move. Scaled by a vanishing norm, the solver's rounding in its direction became
    # a step of 1e135 ADU (found as a user: "device_intensity -2.9e+135 ADU is drawn as
    # 0" on ColiCoords ds1); its mean was unchanged, its number nonsense.
    free = diagonal > 0
    scale = np.sqrt(np.where(free, diagonal, 1.0))
    scaled, b = normal / np.outer(scale, scale), rhs / scale
    for damping in (0.0, *DAMPING):
        if damping == 0.0:
            z = np.linalg.lstsq(scaled, b, rcond=1e-12)[0]
        else:
            z = np.linalg.solve(scaled + damping * np.eye(len(b)), b)
        z = np.where(free, z, 0.0)
        with np.errstate(over="ignore", invalid="ignore"):
            trial_beta, trial_effects, trial_mu = _trial(design, beta, effects, z / scale)
            trial_cost = float(np.sum(w * (yv - trial_mu.ravel()[idx]) ** 2))
            if penalty is not None:
                p = _params_vector(trial_beta, trial_effects)
                trial_cost += float(p @ penalty @ p)
        if math.isfinite(trial_cost) and trial_cost <= cost * (1 + 1e-9):
            return trial_beta, trial_effects, trial_mu
    return beta, effects, mu


def _random_field_penalty(beta, effects, normal, rhs) -> tuple[np.ndarray | None, list]:
    """Precision ``I_eff / tau^2`` of each random-field effect (empirical Bayes).

    The coefficients ``theta`` of a random field are taken as ``N(0, tau^2 I_eff^-1)``
    (Zellner's g-prior: the field is as likely in every direction the data can see).
    Then the score test of ``tau^2 = 0`` is the effect's ordinary ``chi2(k)`` score
    test, the whitened score ``z = I_eff^-1/2 U`` is ``N(0, (1 + tau^2) I_k)``, so
    ``tau^2 = max(|z|^2 / k - 1, 0)`` maximises the marginal likelihood, and the
    penalised fit is the free fit shrunk by ``tau^2 / (1 + tau^2) = 1 - k / |z|^2``
    (positive part). ``tau^2`` comes from this fit's own pixels (the efficient score
    at ``theta = 0`` with the other parameters projected out; the normal equations
    are linear in ``theta``), so every held-out fit and bootstrap replicate estimates
    its own. Returns the penalty (``None`` when no effect is a random field) and the
    shrinkage of each effect.
    """
    sizes = [len(beta), *[len(t) for _, t in effects]]
    starts = np.cumsum([0, *sizes])
    penalty = None
    shrinkage = [1.0] * len(effects)
    for i, (effect, theta) in enumerate(effects):
        if not effect.random_field or not len(theta):
            continue
        t = np.arange(starts[i + 1], starts[i + 2])
        n = np.setdiff1d(np.arange(len(rhs)), t)
        solve = np.linalg.pinv(normal[np.ix_(n, n)], rcond=1e-10)
        info = normal[np.ix_(t, t)] - normal[np.ix_(t, n)] @ solve @ normal[np.ix_(n, t)]
        score = rhs[t] - normal[np.ix_(t, n)] @ solve @ rhs[n] + info @ np.asarray(theta)
        evals, evecs = np.linalg.eigh(info)
        keep = evals > max(float(evals.max(initial=0.0)), 0.0) * 1e-9
        z2 = float(np.sum((evecs[:, keep].T @ score) ** 2 / evals[keep]))
        tau2 = max(z2 / max(int(keep.sum()), 1) - 1.0, 0.0)
        shrinkage[i] = tau2 / (1.0 + tau2)
        if penalty is None:
            penalty = np.zeros((len(rhs), len(rhs)))
        # tau^2 = 0 (no field): 1e12 times the information holds theta at 0
        penalty[np.ix_(t, t)] = info / max(tau2, 1e-12)
    return penalty, shrinkage


def fit_model(
    design: BaseDesign,
    y: np.ndarray,
    mask: np.ndarray,
    effects: Sequence[tuple[Effect, np.ndarray]] = (),
    *,
    fit_camera: bool = False,
    censor: Censor | None = None,
    rounds: int = 4,
    beta0: np.ndarray | None = None,
) -> FittedModel:
    """Iteratively reweighted Gauss-Newton fit on the pixels in ``mask``.

    Parameters
    ----------
    design
        The nuisance design.
    y
        Observed image above the baseline, ``(T, Y, X)`` ADU.
    mask
        Pixels to fit (e.g. three of the four held-out folds).
    effects
        ``(effect, start parameters)`` pairs, applied in order to the base mean.
    fit_camera
        Also fit the gain and read-noise factors of the variance (``camera_noise``).
    censor
        Clipped pixels (``saturation``): fitted by their censored likelihood, each
        clipped value replaced in every step by its expectation beyond the clip under
        the current model (the EM algorithm of a censored normal model). Left out, as
        before 2026-12-04, they biased the mean towards the unclipped side (found as a
        user: ColiCoords' background-subtracted field 00003, 18 % of its pixels at 0,
        had a residual after ``saturation`` of -0.30 s.d. on average, the model too
        bright everywhere).
    """
    beta = design.start() if beta0 is None else np.array(beta0, float)
    effects = [(e, np.array(t, float)) for e, t in effects]
    gain = read = 1.0
    fit_mask = mask & ~censor.mask(y) if censor is not None else mask
    idx = np.flatnonzero(mask.ravel())
    observed = y.ravel()[idx]
    clipped = censor.mask(observed) if censor is not None else np.zeros(idx.size, bool)
    any_clipped = bool(clipped.any())
    yv = observed
    a = None
    penalty = shrinkage = None
    mu = predict(design, beta, effects)
    for round_index in range(rounds):
        v = variance(mu, design.camera, gain, read).ravel()[idx]
        w = 1.0 / v
        for _inner in range(2 if effects or any_clipped else 1):
            if any_clipped:  # E-step: the clipped values expected under this model
                at = mu.ravel()[idx][clipped]
                yv = observed.copy()
                yv[clipped] = at + np.sqrt(v[clipped]) * censor.standardised_mean(at, v[clipped])
            # The catalogue's effects are linear or nearly so in their parameters: the
            # Jacobian is computed at the start and once more before the last round.
            if a is None or (round_index == rounds - 1 and _inner == 0):
                jac = _jacobian(design, beta, effects, mu)
                a = jac.reshape(len(jac), -1)[:, idx].T
            if _inner == 0:
                # the weights are fixed within a round and the Jacobian is taken only
                # before its first step: the second step reuses the normal matrix
                aw = a * w[:, None]
                a_normal = a.T @ aw
            r = yv - mu.ravel()[idx]
            normal = a_normal
            rhs = aw.T @ r
            cost = float(np.sum(w * r**2))
            if shrinkage is None:
                penalty, shrinkage = _random_field_penalty(beta, effects, normal, rhs)
            if penalty is not None:
                p = _params_vector(beta, effects)
                normal, rhs = normal + penalty, rhs - penalty @ p
                cost += float(p @ penalty @ p)
            beta, effects, mu = _descent_step(
                design, beta, effects, normal, rhs, mu, yv, idx, w, cost, penalty
            )
        if fit_camera:  # on the high-pass residual: a misfit of the mean is not noise
            from napari_symbac.diagnose.effects import camera_noise

            data = ~censor.mask(y) if censor is not None else np.ones(y.shape, bool)
            gain, read = camera_noise.fit_factors(y - mu, mu, design.camera, data, fit_mask)
    mu = predict(design, beta, effects)
    return FittedModel(
        beta,
        tuple(effects),
        gain,
        read,
        censor,
        mu,
        variance(mu, design.camera, gain, read),
        tuple(shrinkage or [1.0] * len(effects)),
    )


def deviance(y: np.ndarray, model: FittedModel, mask: np.ndarray) -> np.ndarray:
    """Per-pixel ``-2 log L`` (Gaussian; censored pixels ``-2 log P(clipped)``) on ``mask``."""
    mu, v = model.mu[mask], model.var[mask]
    yy = y[mask]
    dev = (yy - mu) ** 2 / v + np.log(2 * math.pi * v)
    if model.censor is not None:
        clipped = model.censor.mask(yy)
        tail = special.log_ndtr(-model.censor.clip_z(mu, v))
        dev = np.where(clipped, -2 * tail, dev)
    return dev
