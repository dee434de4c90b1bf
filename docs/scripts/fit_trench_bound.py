"""How far could any cell model take the real trench's fit? A bound by free optical paths.

Run from the repository root::

    python docs/scripts/fit_trench_bound.py [REAL_DATA_DIR]

Fits ``ecoli_100x_oil_exponential.tiff`` (GPL-2 SyMBac sample data, read from
``../shared/data/real``, never copied) twice, as ``fit_trench_residual.py`` does: flat
light, and the best model there (illumination surface of degree 4, per-cell brightness
and widths). Then, keeping each fit's kernel, camera and scene, it frees the optical path
of chosen pixels and solves for them by weighted least squares (``scipy`` LSQR; eq. 3 is
linear in the optical path, so the solve is exact): whatever the missing physics inside
those pixels is (cell texture, outlines, walls), it cannot fit better than this. Prints,
per fit and per freed region, the reduced chi-square and the residual rms over the
camera noise's rms (issue 10's goal: 2). Then the same with a cell model of tens of
parameters per cell: a texture of the optical path in cubic B-splines along each cell
(knots every 0.25 um) times 1, t, t^2 across it, and the cell's width and centre line
along it in the same splines, to first order.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import tifffile
from _args import parse_real_data
from scipy import ndimage, signal
from scipy.interpolate import BSpline
from scipy.sparse.linalg import LinearOperator, lsqr

from napari_symbac.fit import fit_scene
from napari_symbac.optics.forward import ForwardModel
from napari_symbac.settings import Microscope, RenderSettings

MICROSCOPE = Microscope(pixel_size_um=0.065)
MODELS = {
    "flat light": {},
    "degree 4 + per-cell brightness + widths": {
        "illumination_order": 4,
        "per_cell_brightness": True,
        "width_sd_um": 0.1,
    },
}
#: Knot spacing of the per-cell splines (um).
KNOT_UM = 0.25


class Bound:
    """A fit's residual, noise and linear map from camera-pixel optical path to image."""

    def __init__(self, fit) -> None:
        self.fit = fit
        self.kernel = ForwardModel(MICROSCOPE, fit.render).kernel().astype(float)
        self.radius = self.kernel.shape[0] // 2
        self.u = fit.render.upsample
        self.shape = fit.synthetic.shape
        cam = fit.camera
        mean = np.maximum(fit.synthetic.astype(float) - cam.baseline_adu, 0.0)
        variance = (
            cam.sensitivity_adu_per_e * mean + (cam.sensitivity_adu_per_e * cam.dark_noise_e) ** 2
        )
        self.sigma = np.sqrt(variance)
        self.z = fit.residual.astype(float) / self.sigma
        scene = fit.scene
        self.trim = scene.border_px - self.radius
        b = scene.border_px
        rows, cols = self.shape

        def camera(a):
            a = np.asarray(a, float)[b:-b, b:-b]
            return a.reshape(rows, self.u, cols, self.u).mean(axis=(1, 3))

        self.cells = camera(scene.cells) > 0.5
        self.device = camera(scene.device)

    def _average(self, image: np.ndarray) -> np.ndarray:
        rows, cols = self.shape
        return image.reshape(rows, self.u, cols, self.u).mean(axis=(1, 3))

    def image_of(self, path_px: np.ndarray) -> np.ndarray:
        """The image change of a camera-pixel optical-path change (render, convolve, bin)."""
        up = np.repeat(np.repeat(path_px, self.u, 0), self.u, 1)
        valid = signal.fftconvolve(np.pad(up, self.radius), self.kernel, mode="valid")
        return self._average(valid)

    def _adjoint(self, image: np.ndarray) -> np.ndarray:
        rows, cols = self.shape
        up = np.repeat(np.repeat(image, self.u, 0), self.u, 1) / self.u**2
        r = self.radius
        full = signal.fftconvolve(up, self.kernel[::-1, ::-1], mode="full")[r:-r, r:-r]
        return full.reshape(rows, self.u, cols, self.u).sum(axis=(1, 3))

    def free(self, mask: np.ndarray, smooth_px: float = 0.0) -> float:
        """Reduced chi-square with the optical path of ``mask``'s pixels free."""
        index = np.flatnonzero(mask)
        shape = self.shape

        def smooth(a):
            return ndimage.gaussian_filter(a, smooth_px, mode="constant") if smooth_px else a

        def forward(v):
            path = np.zeros(mask.size)
            path[index] = v
            return (self.image_of(smooth(path.reshape(shape))) / self.sigma).ravel()

        def adjoint(w):
            return smooth(self._adjoint(w.reshape(shape) / self.sigma)).ravel()[index]

        op = LinearOperator((mask.size, index.size), forward, adjoint, dtype=float)
        solution = lsqr(op, self.z.ravel(), iter_lim=300)[0]
        return float(np.mean((self.z.ravel() - forward(solution)) ** 2))

    def cell_model(self, across: int, outline: bool) -> tuple[float, int]:
        """Reduced chi-square with a per-cell spline texture (and outline); parameters."""
        scene = self.fit.scene
        cells = np.asarray(scene.cells, float)
        labels = np.asarray(scene.labels)
        px = scene.pixel_size_um
        yy, xx = np.mgrid[0 : cells.shape[0], 0 : cells.shape[1]]
        grid = np.stack([yy, xx], -1).astype(float)
        columns = []
        ids = [i for i in np.unique(labels) if i]
        for cell_id in ids:
            inside = labels == cell_id
            points = grid[inside]
            centre = points.mean(0)
            _, axes = np.linalg.eigh(np.cov((points - centre).T))
            along, across_axis = axes[:, 1], axes[:, 0]
            s = ((grid - centre) @ along) * px
            t = ((grid - centre) @ across_axis) * px
            s0, s1 = s[inside].min(), s[inside].max()
            half_width = np.abs(t[inside]).max()
            n = max(int(np.ceil((s1 - s0) / KNOT_UM)), 1)
            knots = np.concatenate([[s0] * 3, np.linspace(s0, s1, n + 1), [s1] * 3])
            own = np.where(inside, cells, 0.0)
            gy, gx = np.gradient(own)
            sideways = (gy * across_axis[0] + gx * across_axis[1]) / px
            near = ndimage.binary_dilation(inside, iterations=2)
            for j in range(len(knots) - 4):
                coef = np.zeros(len(knots) - 4)
                coef[j] = 1.0
                spline = np.nan_to_num(
                    BSpline(knots, coef, 3, extrapolate=False)(np.clip(s, s0, s1))
                )
                shapes = [own * spline * (t / half_width) ** k for k in range(across)]
                if outline:  # centre line and width along the cell, to first order
                    shapes += [
                        np.where(near, g * spline, 0.0) for g in (sideways, np.sign(t) * sideways)
                    ]
                for path in shapes:
                    cut = path[self.trim : -self.trim or None, self.trim : -self.trim or None]
                    valid = signal.fftconvolve(cut, self.kernel, mode="valid")
                    columns.append((self._average(valid) / self.sigma).ravel())
        design = np.stack(columns, 1)
        coef, *_ = np.linalg.lstsq(design, self.z.ravel(), rcond=None)
        chi2 = float(np.mean((self.z.ravel() - design @ coef) ** 2))
        return chi2, design.shape[1] // len(ids)


def _row(label: str, chi2: float, extra: str = "") -> None:
    print(f"| {label} | {chi2:.2f} | {np.sqrt(chi2):.2f} | {extra} |")


def main(real_dir: Path) -> None:
    image = tifffile.imread(real_dir / "ecoli_100x_oil_exponential.tiff")
    for name, options in MODELS.items():
        t0 = time.perf_counter()
        fit = fit_scene(image, MICROSCOPE, RenderSettings(), closed_end="round", **options)
        bound = Bound(fit)
        walls = (bound.device > 0.05) & (bound.device < 0.95)
        near_cells = ndimage.binary_dilation(bound.cells, iterations=2)
        print(f"\n{name}: {len(fit.cells)} cells ({time.perf_counter() - t0:.0f} s)")
        print("| optical path freed | reduced chi-square | rms / noise rms | |")
        print("|---|---|---|---|")
        _row("nothing (the fit)", float(np.mean(bound.z**2)))
        _row("every pixel of the cells", bound.free(bound.cells), f"{bound.cells.sum()} px")
        _row("the cells, smooth (Gaussian, 3 px)", bound.free(bound.cells, 3.0))
        _row("the cells and 2 px around them", bound.free(near_cells), f"{near_cells.sum()} px")
        trench = near_cells | ndimage.binary_dilation(walls, iterations=2) | (bound.device < 0.95)
        _row("the whole trench and its walls", bound.free(trench), f"{trench.sum()} px")
        for across, outline in ((3, False), (2, True)):
            chi2, per_cell = bound.cell_model(across, outline)
            what = f"texture x {across} across" + (" + width and centre line" if outline else "")
            _row(f"per-cell splines every {KNOT_UM} um: {what}", chi2, f"{per_cell} per cell")
        _row("every pixel (the noise floor)", bound.free(np.ones(bound.shape, bool)))


if __name__ == "__main__":
    main(parse_real_data(__doc__, "ecoli_100x_oil_exponential.tiff"))
