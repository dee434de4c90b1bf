"""The scene model of the fit and its Levenberg-Marquardt solver.

The clean image is linear in the intensities (eq. 3, 15):
``mu = I_c C + I_m M + I_d D`` with ``C, M, D`` the convolved, area-averaged cells,
media and device fractions. Since media = trench - cells, a change of one cell's
parameters changes ``C`` (and ``M = T - C``) only within the cell's bounding box
plus the PSF radius (linearity of the convolution), so each cell's Jacobian
columns come from rendering that patch alone (:meth:`SceneModel.cell_delta`).
The intensities are solved exactly at every evaluation (a 3 x 3 normal-equation
solve with an exact non-negativity fallback, :func:`solve_intensities`). With the
depth-resolved fluorescence image (``RenderSettings.depth_layers``, eq. 16) ``C`` is the
stain's slabs each through its PSF, in the full render and in the patches alike.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from napari_symbac.fit.illumination import illumination_basis, illumination_terms
from napari_symbac.fit.placement import TrenchPlacement, draw_fitted
from napari_symbac.optics import ForwardModel, block_average
from napari_symbac.optics.backends import resample_fft_shape
from napari_symbac.scene import Scene, stain_layers, stained_fraction
from napari_symbac.scene._raster import chord
from napari_symbac.settings import Camera, Microscope, RenderSettings
from napari_symbac.sim import FrameCells

__all__ = ["CURVATURE_B", "CURVATURE_C", "DIFF_STEP", "Layout", "SceneModel", "solve_intensities"]

#: Finite-difference step in scaled units (0.3 x 0.05 um = 15 nm, ~ 2/3 of a render
#: pixel): the chord ``2 sqrt(r^2 - d^2)`` has a square-root cusp at a cell's edge, so
#: steps much smaller than a render pixel give a Jacobian that only sees the cusp.
DIFF_STEP = 0.3
#: ``b`` and ``c`` of eq. 1 for fitted curvature: ``roll(l) = a sin(pi l / b + c)``,
#: ``l`` the fraction of the cell length from its top pole; only ``a`` is fitted.
CURVATURE_B = 1.0
CURVATURE_C = 0.0
#: Scale (optimiser units) of the geometric parameters: um and rad.
SCALE_GEOMETRY = 0.05
_OPTICS_SCALE = {
    "apodisation_sigma_um": 0.1,
    "defocus_sigma_um": 0.05,
    "ring_contrast": 0.1,
    "psf_offset": 0.05,
    "envelope_stain_fraction": 0.1,
    "focus_offset_um": 0.05,
}
_INTENSITIES = ("cell_intensity", "media_intensity", "device_intensity")
#: Render settings that change only the PSF kernel, not the drawn scene (whose
#: upsampling and border come from ``upsample`` and ``psf_radius_px``).
KERNEL_PARAMETERS = frozenset(
    {"apodisation_sigma_um", "defocus_sigma_um", "ring_contrast", "psf_offset"}
)


def solve_intensities(
    a: np.ndarray, y: np.ndarray, w: np.ndarray, signed: int = 0, transmitted: bool = False
) -> np.ndarray:
    """Non-negative weighted least squares ``min sum w (y - a I)^2``, ``I >= 0``, exactly.

    Eq. 3 is linear in the three intensities: the normal equations are 3 x 3. The
    unconstrained solution is returned when it is non-negative; otherwise every
    subset of free intensities (the others held at 0) is solved and the feasible
    one of least cost is returned (the exact NNLS solution for 3 unknowns).
    All-zero columns (no device in an open field) get intensity 0. The last
    ``signed`` columns take either sign (bright field's lens amplitude,
    :attr:`SceneModel.lens`). With ``transmitted`` the cells' intensity (column 0) is
    at most the media's (column 1): in bright field a cell absorbs, it passes no more
    light than the clear media beside it (its bright centre out of focus is the lens
    term's); a solution above is replaced by the best on ``I_c = I_m``.
    """
    if transmitted:
        best = solve_intensities(a, y, w, signed)
        if best[0] <= best[1]:
            return best
        merged = np.column_stack([a[:, 0] + a[:, 1], a[:, 2:]])
        sol = solve_intensities(merged, y, w, signed)
        return np.concatenate([[sol[0]], sol])
    aw = a * w[:, None]
    gram = a.T @ aw
    rhs = aw.T @ y
    k = a.shape[1]
    used = [j for j in range(k) if gram[j, j] > 0]
    best, best_cost = np.zeros(k), 0.0  # cost relative to I = 0
    for size in range(len(used), 0, -1):
        for subset in itertools.combinations(used, size):
            idx = list(subset)
            try:
                sol = np.linalg.solve(gram[np.ix_(idx, idx)], rhs[idx])
            except np.linalg.LinAlgError:
                continue
            cost = -float(sol @ rhs[idx])  # sol' G sol - 2 sol' h at sol = G^-1 h
            nonnegative = [v for j, v in zip(idx, sol) if j < k - signed]
            if np.all(np.asarray(nonnegative) >= 0) and cost < best_cost:
                best = np.zeros(k)
                best[idx] = sol
                best_cost = cost
        if size == len(used) and best_cost < 0:
            break  # the unconstrained optimum is feasible
    return best


@dataclass(frozen=True)
class Layout:
    """Order of the parameter vector: per-cell blocks, then the shared parameters.

    Each cell holds ``x_um, y_um, angle_rad, length_um`` then, when fitted, its
    curvature amplitude ``curvature_um``, its width offset ``dwidth_um`` and its
    relative brightness offset ``dbrightness`` (its intensity is
    ``I_c (1 + dbrightness)``: cells differ in fluorophore content). Then
    come the shared ``width_um``, the trench's ``left_um, width_um`` (and ``top_um``),
    the coefficients of the illumination surface of degree ``illumination``
    (``illumination.<term>``, :mod:`~napari_symbac.fit.illumination`; none when 0)
    and the optical parameters (last: a series shares them between frames).
    """

    n: int
    fit_curvature: bool
    per_cell_width: bool
    trench: bool
    fit_top: bool
    optics: tuple[str, ...]
    per_cell_brightness: bool = False
    illumination: int = 0

    @property
    def illumination_names(self) -> tuple[str, ...]:
        """``illumination.<term>`` for each term of the surface."""
        return tuple(f"illumination.{t}" for t in illumination_terms(self.illumination))

    @property
    def i_illumination(self) -> int:
        """Index of the first illumination coefficient among the shared parameters."""
        return 1 + (2 + self.fit_top if self.trench else 0)

    @property
    def cell_names(self) -> tuple[str, ...]:
        names = ["x_um", "y_um", "angle_rad", "length_um"]
        if self.fit_curvature:
            names.append("curvature_um")
        if self.per_cell_width:
            names.append("dwidth_um")
        if self.per_cell_brightness:
            names.append("dbrightness")
        return tuple(names)

    @property
    def i_dwidth(self) -> int:
        """Index of ``dwidth_um`` within a cell's block."""
        return 4 + self.fit_curvature

    @property
    def i_brightness(self) -> int:
        """Index of ``dbrightness`` within a cell's block."""
        return 4 + self.fit_curvature + self.per_cell_width

    @property
    def per_cell(self) -> int:
        return len(self.cell_names)

    @property
    def global_names(self) -> tuple[str, ...]:
        names = ["width_um"]
        if self.trench:
            names += ["trench.left_um", "trench.width_um"]
            if self.fit_top:
                names.append("trench.top_um")
        return (*names, *self.illumination_names, *self.optics)

    @property
    def size(self) -> int:
        return self.n * self.per_cell + len(self.global_names)

    def names(self, ids: np.ndarray) -> tuple[str, ...]:
        """Parameter names, ``cell<id>.<name>`` for the cells' parameters."""
        cells = [f"cell{int(i)}.{name}" for i in ids for name in self.cell_names]
        return (*cells, *self.global_names)

    def owner(self, k: int) -> int:
        """Index of the cell that parameter ``k`` belongs to, -1 for a shared one."""
        return k // self.per_cell if k < self.n * self.per_cell else -1

    def wrap_angles(self, x: np.ndarray) -> np.ndarray:
        """Each cell's angle into ``[-pi/2, pi/2)`` in place, its curvature's sign
        flipped with each half turn: a rod turned by pi and bent the other way is the same
        rod, drawn identically (tested). The angle's bounds are then no limit of the
        fit (found as a user: horizontal cells were reported "at a bound" at 1.6 rad)."""
        if self.n == 0:
            return x
        block = x[: self.n * self.per_cell].reshape(self.n, self.per_cell)
        turns = np.floor((block[:, 2] + np.pi / 2) / np.pi)
        block[:, 2] -= turns * np.pi
        if self.fit_curvature:
            block[:, 4] *= 1.0 - 2.0 * (turns % 2)
        return x

    def with_cells(self, n: int) -> Layout:
        return dataclasses.replace(self, n=n)

    def scales(self) -> np.ndarray:
        g = [SCALE_GEOMETRY] * (len(self.global_names) - len(self.optics))
        g += [_OPTICS_SCALE.get(name, 0.05) for name in self.optics]
        return np.concatenate([np.full(self.n * self.per_cell, SCALE_GEOMETRY), g])


class SceneModel:
    """Renders a parameter vector (see :class:`Layout`) into the design ``[C, M, D]``.

    Parameters
    ----------
    shape
        Camera shape of the real image.
    microscope, render, camera
        The forward model's settings (``render`` gives the kernel parameters that
        are not fitted).
    placement
        Trench placement (``None``: open field); its depth and closed end are kept.
    depth_um
        Optical depth of the media layer.
    layout
        Order of the parameter vector.
    """

    def __init__(
        self,
        shape: tuple[int, int],
        microscope: Microscope,
        render: RenderSettings,
        camera: Camera,
        placement: TrenchPlacement | None,
        depth_um: float,
        layout: Layout,
        tick: Callable[[], None] | None = None,
    ) -> None:
        self.shape = shape
        self.microscope = microscope
        self.render = render
        self.placement = placement
        self.depth_um = depth_um
        self.layout = layout
        self.forward = ForwardModel(microscope, render, camera)
        self.tick = tick if tick is not None else (lambda: None)
        self._box_cache: tuple | None = None
        basis = illumination_basis(shape, layout.illumination)
        self._light_basis = basis.reshape(basis.shape[0], shape[0] * shape[1])

    @property
    def lens(self) -> bool:
        """Bright field: a fourth design column, the cells' phase through the lens
        kernel ``laplacian(k)`` (:func:`~napari_symbac.optics.psf.brightfield_kernels`),
        its amplitude ``kappa I_m`` solved with the intensities, of either sign."""
        return self.microscope.modality == "brightfield"

    @property
    def n_amplitudes(self) -> int:
        """Columns of the design: the three intensities, and bright field's lens."""
        return 4 if self.lens else 3

    def lens_column(self, forward: ForwardModel, scene: Scene) -> np.ndarray:
        """``-laplacian(k)`` convolved with the cells' fraction (camera pixels, flat,
        float64): the lens column of :meth:`design` (its amplitude ``kappa I_m``)."""
        ring = forward.ring_kernel(scene.pixel_size_um)
        return -self._convolve(forward, scene, (scene.cells,), kernel=ring)[0].ravel().astype(
            np.float64
        )

    def light(self, x: np.ndarray) -> np.ndarray | None:
        """The illumination surface ``1 + sum_k c_k P_k`` of ``x`` (flat), ``None`` when off."""
        k = self._light_basis.shape[0]
        if k == 0:
            return None
        start = self.layout.n * self.layout.per_cell + self.layout.i_illumination
        return 1.0 + x[start : start + k] @ self._light_basis

    # ------------------------------------------------------------------ unpack
    def unpack(
        self, x: np.ndarray
    ) -> tuple[
        FrameCells, dict[int, tuple[float, float, float]], TrenchPlacement | None, RenderSettings
    ]:
        """Cells, curvature, trench placement and render settings of ``x``."""
        lay = self.layout
        n, pc = lay.n, lay.per_cell
        block = x[: n * pc].reshape(n, pc) if n else np.zeros((0, pc))
        g = x[n * pc :]
        width = np.full(n, g[0])
        if lay.per_cell_width:
            width = width + block[:, lay.i_dwidth]
        width = np.maximum(width, 0.2)
        cells = FrameCells(
            ids=np.arange(1, n + 1),
            x_um=block[:, 0].copy(),
            y_um=block[:, 1].copy(),
            angle_rad=block[:, 2].copy(),
            length_um=np.maximum(block[:, 3], width),
            width_um=width,
        )
        curvature = {}
        if lay.fit_curvature:
            for i in range(n):
                if block[i, 4] != 0:
                    curvature[i + 1] = (float(block[i, 4]), CURVATURE_B, CURVATURE_C)
        place = None
        j = 1
        if lay.trench and self.placement is not None:
            top = g[3] if lay.fit_top else self.placement.top_um
            place = TrenchPlacement(
                float(g[1]),
                float(g[2]),
                float(top),
                self.placement.depth_um,
                self.placement.closed_end,
            )
            j = 4 if lay.fit_top else 3
        j += len(lay.illumination_names)
        values = {name: float(v) for name, v in zip(lay.optics, g[j:])}
        return cells, curvature, place, dataclasses.replace(self.render, **values)

    # ---------------------------------------------------------------- full render
    def design(self, x: np.ndarray) -> tuple[np.ndarray, Scene, RenderSettings]:
        """``(pixels, 3)`` design ``[C, M, D]`` (float64), the scene and the render settings.

        Cells, media and device fractions add up to 1 at every render pixel, so two
        transforms give all three columns: ``C`` and the trench ``T = C + M``; then
        ``M = T - C`` and ``D = K - T``, ``K`` the kernel's sum (the convolution of
        1). An open field has ``T = K`` (no device), one transform. With per-cell
        brightness the cells column is ``C + sum_i db_i C_i`` (``C_i`` the convolved
        fraction of cell ``i`` alone); by the linearity of the convolution it is the
        convolution of ``cells + sum_i db_i F_i`` (:meth:`_brightness`), one more
        transform for all cells. With part of a fluorescence stain in the envelope
        (``envelope_stain_fraction``, :meth:`_cells_image`) the cells column is the
        stain's image and the media column ``T`` less the cells' volume's. With an
        illumination surface every row is multiplied by it (:meth:`light`).
        """
        self.tick()
        cells, curvature, place, r = self.unpack(x)
        scene = draw_fitted(cells, place, self.shape, self.microscope, r, self.depth_um, curvature)
        forward = self.forward.with_render(r)
        layered = self._layers(r) > 0
        stain = None if layered else self._cells_image(x, scene, r)
        own_stain = stain is not scene.cells  # the stain differs from the cells' volume
        images = [stain, scene.cells] if own_stain and not layered else [scene.cells]
        open_field = not scene.device.any()
        if not open_field:
            images.append(1.0 - scene.device)
        convolved = self._convolve(forward, scene, tuple(images)).astype(np.float64)
        whole = float(np.sum(forward.kernel(scene.pixel_size_um), dtype=np.float64))
        trench = np.full(convolved.shape[1:], whole) if open_field else convolved[-1]
        cells = convolved[1 if own_stain and not layered else 0]
        if layered:
            stained = self._convolve_layers(forward, scene, self._cells_layers(x, scene, r))
        else:
            stained = convolved[0]
        columns = [stained.ravel(), (trench - cells).ravel(), (whole - trench).ravel()]
        if self.lens:
            columns.append(self.lens_column(forward, scene))
        a = np.stack(columns, axis=1)
        light = self.light(x)
        if light is not None:
            a *= light[:, None]  # the surface multiplies eq. 3: still linear in I
        return a, scene, r

    def _layers(self, r: RenderSettings) -> int:
        """Slabs of the depth-resolved stain (eq. 16; 0: the 2-D projection, and always
        in phase contrast)."""
        return r.depth_layers if self.microscope.modality == "fluorescence" else 0

    def _cells_layers(self, x: np.ndarray, scene: Scene, r: RenderSettings) -> np.ndarray:
        """The stain of :meth:`_cells_image` in the slabs of ``r.depth_layers``
        (:func:`~napari_symbac.scene.stain_layers`), per-cell brightness included."""
        radius = self._radius_lut(x)[scene.labels]
        fraction, n_layers = self._fraction(r), self._layers(r)
        layers = stain_layers(scene.cells, radius, fraction, self.depth_um, n_layers)
        if self.layout.per_cell_brightness:
            layers += self._brightness(x, scene, r)
        return layers

    def _convolve_layers(
        self, forward: ForwardModel, scene: Scene, layers: np.ndarray
    ) -> np.ndarray:
        """The slabs through their PSFs (eq. 16), summed and area-averaged, float64."""
        trim = scene.border_px - forward.render_settings.psf_radius_px
        if trim:
            layers = layers[:, trim:-trim, trim:-trim]
        kernels = forward.depth_kernels(self.depth_um, scene.pixel_size_um)
        return forward.convolve_depth(layers, kernels, scene.upsample).astype(np.float64)

    def _fraction(self, r: RenderSettings) -> float:
        """The envelope's fraction of the stain the model draws (0 in phase contrast)."""
        return r.envelope_stain_fraction if self.microscope.modality == "fluorescence" else 0.0

    def _radius_lut(self, x: np.ndarray) -> np.ndarray:
        """Radius (um) of every cell at ``x``, indexed by its label (``[0]`` = 0)."""
        lay = self.layout
        n, pc = lay.n, lay.per_cell
        block = x[: n * pc].reshape(n, pc)
        width = np.full(n, x[n * pc]) + (block[:, lay.i_dwidth] if lay.per_cell_width else 0.0)
        return np.concatenate([[0.0], np.maximum(width, 0.2) / 2])

    def _cells_image(self, x: np.ndarray, scene: Scene, r: RenderSettings) -> np.ndarray:
        """The cells' stain at render resolution: the cells fraction, with
        ``envelope_stain_fraction`` of it in the envelope (as
        :func:`~napari_symbac.scene.envelope_stain` draws it, each cell's radius its
        fitted width's half, as the patches of :meth:`cell_deltas` take it) and the
        per-cell brightness (:meth:`_brightness`); ``scene.cells`` itself when neither
        applies."""
        image = scene.cells
        fraction = self._fraction(r)
        if fraction:
            radius = self._radius_lut(x)[scene.labels]
            image = stained_fraction(image, radius, fraction, self.depth_um)
        if self.layout.per_cell_brightness:
            image = image + self._brightness(x, scene, r)
        return image

    def _convolve(
        self,
        forward: ForwardModel,
        scene: Scene,
        images: tuple[np.ndarray, ...],
        weights: np.ndarray | None = None,
        kernel: np.ndarray | None = None,
    ) -> np.ndarray:
        """Render-resolution images through the forward model's PSF (or ``kernel``) and
        resample stages.

        The same transform as :meth:`ForwardModel.components` (trimmed to the PSF
        border, convolved, block-averaged); with ``weights`` the weighted sum of the
        images in one transform (linearity).
        """
        trim = scene.border_px - forward.render_settings.psf_radius_px
        stack = np.stack([np.asarray(image, np.float32) for image in images])
        if trim:
            stack = stack[:, trim:-trim, trim:-trim]
        if kernel is None:
            kernel = forward.kernel(scene.pixel_size_um)
        out = forward._convolve_resample(stack, kernel, scene.upsample, weights)
        return out[None] if weights is not None and out.ndim == 2 else out

    def _brightness(self, x: np.ndarray, scene: Scene, r: RenderSettings) -> np.ndarray:
        """``sum_i db_i F_i`` at render resolution, ``F_i`` cell ``i``'s fraction alone.

        ``F_i = min(chord_i / depth, 1, trench)`` in the cell's box, as
        :meth:`cell_delta` draws it with ``alone`` (its stain: part of it in the
        envelope when ``r`` says so; in the slabs of ``r.depth_layers``, leading axis,
        when there are any).
        """
        fraction = self._fraction(r)
        n_layers = self._layers(r)
        lay = self.layout
        pc, ib = lay.per_cell, lay.i_brightness
        out = np.zeros((n_layers, *scene.shape) if n_layers else scene.shape, np.float32)
        trench = None
        px, bd = scene.pixel_size_um, scene.border_px
        S0, S1 = scene.shape
        for i in range(lay.n):
            db = float(x[i * pc + ib])
            if db == 0:
                continue
            e0, e1, f0, f1, (cx, cy, ang, ln, wd, bend) = self._cell_box(x, i, scene)
            e0, e1, f0, f1 = max(e0, 0), min(e1, S0), max(f0, 0), min(f1, S1)
            if e0 >= e1 or f0 >= f1:
                continue
            if trench is None:
                trench = scene.cells + scene.media
            yc = (np.arange(e0, e1) - bd + 0.5) * px
            xc = (np.arange(f0, f1) - bd + 0.5) * px
            thickness_um = chord(
                xc, yc, (cx, cy), ang, ln, wd, (bend, CURVATURE_B, CURVATURE_C) if bend else None
            )
            alone = np.minimum(
                np.minimum(thickness_um / np.float32(self.depth_um), 1.0), trench[e0:e1, f0:f1]
            )
            if n_layers:
                alone = stain_layers(alone, wd / 2, fraction, self.depth_um, n_layers)
            else:
                alone = stained_fraction(alone, wd / 2, fraction, self.depth_um)
            out[..., e0:e1, f0:f1] += np.float32(db) * alone
        return out

    def kernel_column(
        self, x: np.ndarray, xk: np.ndarray, scene: Scene, intensities: np.ndarray
    ) -> np.ndarray:
        """``mu`` at ``xk``, which differs from ``x`` only in kernel parameters.

        The scene is the same, so no redraw: the fractions (brightness folded into the
        cells) are weighted by the intensities and convolved once with the new kernel.
        """
        self.tick()
        r = self.unpack(xk)[3]
        forward = self.forward.with_render(r)
        weights = np.asarray(intensities, np.float32)
        if self._layers(r):
            stained = self._convolve_layers(forward, scene, self._cells_layers(x, scene, r))
            rest = self._convolve(forward, scene, (scene.media, scene.device), weights[1:3])[0]
            mu = (intensities[0] * stained + rest).ravel()
        else:
            images = (self._cells_image(x, scene, r), scene.media, scene.device)
            mu = self._convolve(forward, scene, images, weights[:3])[0].ravel().astype(np.float64)
        if self.lens:
            mu += intensities[3] * self.lens_column(forward, scene)
        light = self.light(x)
        return mu if light is None else mu * light

    # ---------------------------------------------------------------- patch render
    def _cell_box(
        self, x: np.ndarray, i: int, scene: Scene
    ) -> tuple[int, int, int, int, tuple[float, ...]]:
        """Render-pixel box (scene coordinates) of cell ``i`` and its drawing arguments."""
        lay = self.layout
        pc = lay.per_cell
        b = x[i * pc : (i + 1) * pc]
        g0 = x[lay.n * pc]
        width = max(g0 + (b[lay.i_dwidth] if lay.per_cell_width else 0.0), 0.2)
        length = max(b[3], width)
        bend = float(b[4]) if lay.fit_curvature else 0.0
        px = scene.pixel_size_um
        border = scene.border_px
        half_len, half_wid = length / 2, width / 2 + abs(bend)
        sin_a, cos_a = abs(math.sin(b[2])), abs(math.cos(b[2]))
        reach_x = min(half_len * sin_a + half_wid * cos_a, half_len + half_wid) + 2 * px
        reach_y = min(half_len * cos_a + half_wid * sin_a, half_len + half_wid) + 2 * px
        j0 = math.floor((b[0] - reach_x) / px) + border
        j1 = math.ceil((b[0] + reach_x) / px) + border + 1
        i0 = math.floor((b[1] - reach_y) / px) + border
        i1 = math.ceil((b[1] + reach_y) / px) + border + 1
        args = (float(b[0]), float(b[1]), float(b[2]), float(length), float(width), bend)
        return i0, i1, j0, j1, args

    def _boxes(
        self, x: np.ndarray, scene: Scene
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Render-pixel boxes ``(i0, i1, j0, j1)`` of every cell, as :meth:`_cell_box`.

        Vectorised and kept for the last ``x`` (a Jacobian asks for them once per
        patch), so that finding a patch's neighbours costs O(n), not n boxes.
        """
        key = (x.tobytes(), scene.pixel_size_um, scene.border_px)
        if self._box_cache is not None and self._box_cache[0] == key:
            return self._box_cache[1]
        lay = self.layout
        n, pc = lay.n, lay.per_cell
        b = x[: n * pc].reshape(n, pc)
        width = x[n * pc] + (b[:, lay.i_dwidth] if lay.per_cell_width else 0.0)
        width = np.maximum(width, 0.2)
        length = np.maximum(b[:, 3], width)
        bend = b[:, 4] if lay.fit_curvature else np.zeros(n)
        px, border = scene.pixel_size_um, scene.border_px
        half_len, half_wid = length / 2, width / 2 + np.abs(bend)
        sin_a, cos_a = np.abs(np.sin(b[:, 2])), np.abs(np.cos(b[:, 2]))
        reach_x = np.minimum(half_len * sin_a + half_wid * cos_a, half_len + half_wid) + 2 * px
        reach_y = np.minimum(half_len * cos_a + half_wid * sin_a, half_len + half_wid) + 2 * px
        boxes = (
            np.floor((b[:, 1] - reach_y) / px).astype(np.int64) + border,
            np.ceil((b[:, 1] + reach_y) / px).astype(np.int64) + border + 1,
            np.floor((b[:, 0] - reach_x) / px).astype(np.int64) + border,
            np.ceil((b[:, 0] + reach_x) / px).astype(np.int64) + border + 1,
        )
        self._box_cache = (key, boxes)
        return boxes

    def cell_delta(
        self,
        x: np.ndarray,
        x_new: np.ndarray,
        i: int,
        scene: Scene,
        kernel: np.ndarray,
        alone: bool = False,
    ) -> tuple[int, int, np.ndarray]:
        """Change of the convolved cells image ``C`` when cell ``i`` moves from ``x`` to ``x_new``.

        Only cell ``i``'s parameters (and the shared width) may differ between ``x``
        and ``x_new``; :meth:`cell_deltas` for one ``x_new``.

        With ``alone``, the convolved fraction of cell ``i`` by itself (at ``x_new``).

        Returns
        -------
        row0, col0, patch
            Camera-pixel position of the patch's top-left corner (may be negative or
            reach past the image: clip when adding) and the patch (float64).
        """
        row0, col0, patches = self.cell_deltas(x, [x_new], i, scene, kernel, alone)
        return row0, col0, patches[0]

    def cell_deltas(
        self,
        x: np.ndarray,
        x_news: list[np.ndarray],
        i: int,
        scene: Scene,
        kernel: np.ndarray,
        alone: bool = False,
    ) -> tuple[int, int, np.ndarray]:
        """:meth:`cell_delta` for several moves of cell ``i`` at once, in one patch.

        Each ``x_new`` differs from ``x`` in cell ``i``'s parameters or the shared
        width only; cell ``i`` is drawn from it, the other cells from ``x``. The cells
        fraction is redrawn in the union of the cell's boxes (as
        :func:`~napari_symbac.scene.draw_scene` does: the thickest chord of any cell,
        over the depth, capped by 1 and by the trench; with part of a fluorescence
        stain in the envelope, its stain, each pixel's by the radius of its thickest
        cell: :func:`~napari_symbac.scene.stained_fraction`), the differences are
        convolved with the kernel in full and area-averaged to camera pixels, all in
        one batch of transforms (:meth:`_convolve_patch`; with ``depth_layers``, the
        stain's slabs, each through its PSF: ``kernel`` is then the stack of
        :meth:`~napari_symbac.optics.ForwardModel.depth_kernels`). The Jacobian weighs a
        patch by ``I_c - I_m``: with the stain in the envelope the media's part of it
        (the cells' volume) is taken as the stain's, first order in ``I_m / I_c``,
        which is small in fluorescence.

        Returns
        -------
        row0, col0, patches
            Camera-pixel position of the patches' top-left corner (may be negative or
            reach past the image: clip when adding) and ``(len(x_news), h, w)``
            patches (float64).
        """
        u, bd = scene.upsample, scene.border_px
        S0, S1 = scene.shape
        boxes = [self._cell_box(xn, i, scene) for xn in (x, *x_news)]
        i0, i1 = min(b[0] for b in boxes), max(b[1] for b in boxes)
        j0, j1 = min(b[2] for b in boxes), max(b[3] for b in boxes)
        s0 = 2 * bd + u * math.floor((i0 - 2 * bd) / u)
        s1 = u * math.ceil(i1 / u)
        t0 = 2 * bd + u * math.floor((j0 - 2 * bd) / u)
        t1 = u * math.ceil(j1 / u)
        r0, r1 = max(s0, 0), min(s1, S0)
        q0, q1 = max(t0, 0), min(t1, S1)
        render = self.unpack(x)[3]
        fraction, n_layers = self._fraction(render), self._layers(render)
        slabs = (n_layers,) if n_layers else ()
        delta = np.zeros((len(x_news), *slabs, s1 - s0, t1 - t0), np.float32)

        def stain(image: np.ndarray, radius: np.ndarray | float) -> np.ndarray:
            if n_layers:
                return stain_layers(image, radius, fraction, self.depth_um, n_layers)
            return stained_fraction(image, radius, fraction, self.depth_um)

        if r0 < r1 and q0 < q1:
            px = scene.pixel_size_um
            yc = (np.arange(r0, r1) - bd + 0.5) * px
            xc = (np.arange(q0, q1) - bd + 0.5) * px

            def thickness(args: tuple[float, ...]) -> np.ndarray:
                cx, cy, ang, ln, wd, bend = args
                bent = (bend, CURVATURE_B, CURVATURE_C) if bend else None
                return chord(xc, yc, (cx, cy), ang, ln, wd, bent)

            others = np.zeros((r1 - r0, q1 - q0), np.float32)
            others_radius = np.zeros((r1 - r0, q1 - q0))  # the thickest other cell's
            if not alone:  # the cells whose boxes reach the patch (boxes of x, all at once)
                b0, b1, c0, c1 = self._boxes(x, scene)
                hit = (b1 > r0) & (b0 < r1) & (c1 > q0) & (c0 < q1)
                hit[i] = False
                for j in np.flatnonzero(hit):
                    e0, e1, f0, f1, args = self._cell_box(x, int(j), scene)
                    if e1 <= r0 or e0 >= r1 or f1 <= q0 or f0 >= q1:
                        continue
                    other = thickness(args)
                    if fraction:
                        others_radius[other > others] = args[4] / 2
                    np.maximum(others, other, out=others)
            old = scene.cells[r0:r1, q0:q1]
            trench = old + scene.media[r0:r1, q0:q1]
            if alone:
                old = np.zeros((*slabs, *old.shape), np.float32)
            elif fraction or n_layers:  # the scene's stain, each pixel's cell's radius at x
                old = stain(old, self._radius_lut(x)[scene.labels[r0:r1, q0:q1]])
            depth = np.float32(self.depth_um)
            for m, (e0, e1, f0, f1, args) in enumerate(boxes[1:]):
                thick, radius = others, others_radius
                if not (e1 <= r0 or e0 >= r1 or f1 <= q0 or f0 >= q1):
                    own = thickness(args)
                    thick = np.maximum(others, own)
                    radius = np.where(own > others, args[4] / 2, others_radius)
                new = stain(np.minimum(np.minimum(thick / depth, 1.0), trench), radius)
                delta[m, ..., r0 - s0 : r1 - s0, q0 - t0 : q1 - t0] = new - old
        if n_layers:
            patches = sum(
                self._convolve_patch(np.ascontiguousarray(delta[:, k]), kernel[k], u)
                for k in range(n_layers)
            )
        else:
            patches = self._convolve_patch(delta, kernel, u)
        return (s0 - 2 * bd) // u, (t0 - 2 * bd) // u, patches

    def _convolve_patch(self, patch: np.ndarray, kernel: np.ndarray, factor: int) -> np.ndarray:
        """``fftconvolve(patch, kernel, "full")`` block-averaged ``factor x factor`` (float64),
        for each of ``(N, Y, X)`` patches.

        The full convolution of a patch is the valid convolution of the patch with
        ``kernel - 1`` zeros on every side. The backend's fused convolution + block
        average (:meth:`~napari_symbac.optics.backends.ScipyBackend.convolve_resample_circular`:
        one forward transform at render resolution, the inverse ``factor**2`` times
        smaller, the kernel's spectrum cached per transform size) needs the zeros
        before the patch only: its transform pads the rest, and the circular wrap
        lands in the leading zeros. The full output's sides are multiples of
        ``factor`` (the caller aligns the patch).
        """
        ky, kx = kernel.shape
        n, height, width = patch.shape
        rows, cols = height + ky - 1, width + kx - 1
        padded = np.zeros((n, rows + ky - 1, cols + kx - 1), np.float32)
        padded[:, ky - 1 : rows, kx - 1 : cols] = patch
        backend = self.forward.backend
        fused = getattr(backend, "convolve_resample_circular", None)
        if fused is None:  # a backend without the fused transform
            return block_average(backend.convolve_valid(padded, kernel), factor).astype(np.float64)
        shape = resample_fft_shape(rows, cols, factor)
        out_shape = (rows // factor, cols // factor)
        return fused(padded[:, :rows, :cols], kernel, factor, shape, out_shape).astype(np.float64)

    # ----------------------------------------------------------------- Jacobian
    def jacobian(
        self,
        x: np.ndarray,
        a: np.ndarray,
        intensities: np.ndarray,
        scene: Scene,
        render: RenderSettings,
        free: np.ndarray,
        step: float = DIFF_STEP,
        upper: np.ndarray | None = None,
    ) -> sparse.csc_matrix:
        """``d mu / d z`` (ADU per optimiser unit) for the free parameters and the intensities.

        Rows are all camera pixels (row-major), columns the free parameters in order,
        then the three intensities (per ADU). Cell parameters come from
        :meth:`cell_delta` (forward differences of ``step`` scaled units, backwards at
        an upper bound), times the illumination surface when there is one; the
        surface's coefficients are exact (``d mu / d c_k = P_k mu / light``);
        the other shared parameters come from full renders.
        """
        scales = self.layout.scales()
        forward = self.forward.with_render(render)
        if self._layers(render):
            kernel = forward.depth_kernels(self.depth_um, scene.pixel_size_um)
        else:
            kernel = forward.kernel(scene.pixel_size_um)
        rows, cols = self.shape
        npx = rows * cols
        mu = a @ intensities
        lay = self.layout
        pc = lay.per_cell
        bright = np.ones(lay.n)
        if lay.per_cell_brightness:
            bright += x[: lay.n * pc].reshape(lay.n, pc)[:, lay.i_brightness]
        contrast = intensities[0] * bright - intensities[1]
        light = self.light(x)
        first_light = lay.n * pc + lay.i_illumination
        n_light = self._light_basis.shape[0]
        width_k = lay.n * pc
        steps, moved = {}, {}
        for k in np.flatnonzero(free):
            h = step
            if upper is not None and x[k] + h * scales[k] > upper[k]:
                h = -step
            xk = x.copy()
            xk[k] += h * scales[k]
            steps[int(k)], moved[int(k)] = h, xk
        # Each cell's geometric columns (and its part of the shared width's) in one
        # batch of patches.
        geometric = [
            k
            for k in steps
            if k == width_k
            or (
                lay.owner(k) >= 0
                and not (lay.per_cell_brightness and k % pc == lay.i_brightness)
            )
        ]
        patches: dict[tuple[int, int], tuple[int, int, np.ndarray]] = {}
        # bright field: d mu = I_c' dC conv k - L dC conv laplacian(k), one kernel per
        # cell and the patch weighed by 1 (the lens amplitude L need not share a sign
        # with the contrast, which is 0 for a transparent cell)
        ring = forward.ring_kernel(scene.pixel_size_um) if self.lens else None
        weight = np.ones(lay.n) if self.lens else contrast
        for i in range(lay.n):
            ks = [k for k in geometric if k == width_k or lay.owner(k) == i]
            if not ks:
                continue
            for _ in ks:
                self.tick()
            own = kernel
            if ring is not None:
                own = (contrast[i] * kernel - intensities[3] * ring).astype(np.float32)
            row0, col0, batch = self.cell_deltas(x, [moved[k] for k in ks], i, scene, own)
            for k, patch in zip(ks, batch):
                patches[i, k] = (row0, col0, patch)
        data, indices, indptr = [], [], [0]
        for k in steps:
            h, xk = steps[k], moved[k]
            owner = lay.owner(k)
            shared_width = k == width_k
            if first_light <= k < first_light + n_light:
                # mu = light * mu_0 and light is linear in c_k: exact.
                col = mu / light * self._light_basis[k - first_light] * scales[k]
            elif owner >= 0 and lay.per_cell_brightness and k % pc == lay.i_brightness:
                # Brightness is linear: d mu / d z = I_c C_i scale.
                col = np.zeros(npx)
                self.tick()
                patch = self.cell_delta(x, x, owner, scene, kernel, True)
                _add_patch(col, self.shape, *patch, intensities[0] * scales[k])
                if light is not None:
                    col *= light
            elif owner >= 0 or shared_width:
                # One cell's parameter: its patch. The shared width: the sum of every
                # cell's patch (exact while cells do not overlap, which the overlap
                # penalty keeps so).
                col = np.zeros(npx)
                for i in [owner] if owner >= 0 else range(lay.n):
                    _add_patch(col, self.shape, *patches[i, k], weight[i] / h)
                if light is not None:
                    col *= light
            elif lay.global_names[k - lay.n * pc] in KERNEL_PARAMETERS:
                # The kernel alone changes: one weighted transform, no redraw.
                col = (self.kernel_column(x, xk, scene, intensities) - mu) / h
            else:
                ak, _, _ = self.design(xk)
                col = (ak @ intensities - mu) / h
            nz = np.flatnonzero(col)
            indices.append(nz)
            data.append(col[nz])
            indptr.append(indptr[-1] + indices[-1].size)
        for j in range(a.shape[1]):
            nz = np.flatnonzero(a[:, j])
            indices.append(nz)
            data.append(a[nz, j])
            indptr.append(indptr[-1] + nz.size)
        return sparse.csc_matrix(
            (np.concatenate(data), np.concatenate(indices), np.array(indptr)),
            shape=(npx, len(indptr) - 1),
        )


def _add_patch(
    flat: np.ndarray,
    shape: tuple[int, int],
    row0: int,
    col0: int,
    patch: np.ndarray,
    factor: float,
) -> None:
    """``flat`` (a row-major image) += ``factor * patch`` placed at ``(row0, col0)``, clipped."""
    rows, cols = shape
    ph, pw = patch.shape
    r0, r1 = max(row0, 0), min(row0 + ph, rows)
    c0, c1 = max(col0, 0), min(col0 + pw, cols)
    if r1 <= r0 or c1 <= c0:
        return  # wholly outside the image
    view = flat.reshape(rows, cols)
    view[r0:r1, c0:c1] += factor * patch[r0 - row0 : r1 - row0, c0 - col0 : c1 - col0]
