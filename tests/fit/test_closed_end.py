"""The fit chooses the trench's closed end, square or round, by the image."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _fit_synthetic import PIXEL_UM, TRENCH, TRUTH, make_cells

from napari_symbac.fit import fit_scene
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene
from napari_symbac.settings import Camera, Microscope, RenderSettings


@pytest.mark.parametrize("closed_end", ["square", "round"])
def test_the_closed_end_the_image_shows_is_chosen(closed_end):
    """A trench rendered with either end is fitted with that end, from the default
    square start, and the choice is said among the fit's moves; given, it is kept."""
    trench = dataclasses.replace(TRENCH, closed_end=closed_end, top_margin_um=0.5)
    cells = make_cells(y_um=[1.7, 4.3, 6.9], length_um=[2.3, 2.6, 2.2])
    microscope = Microscope(pixel_size_um=PIXEL_UM)
    scene = draw_scene(cells, trench, microscope, TRUTH)
    image = ForwardModel(microscope, TRUTH, Camera()).render(scene, np.random.default_rng(3))
    options = {"geometry": "trench", "irls_rounds": 1, "max_iterations": 8, "moves": False}
    fit = fit_scene(image, microscope, TRUTH, Camera(), **options)
    assert fit.trench.closed_end == closed_end
    assert fit.moves[0].startswith(f"closed end: {closed_end}, which fits better")
    other = "round" if closed_end == "square" else "square"
    given = fit_scene(image, microscope, TRUTH, Camera(), closed_end=other, **options)
    assert given.trench.closed_end == other
    assert not given.moves
    assert given.objective_after > fit.objective_after


def test_a_window_below_the_closed_end_starts_with_the_end_above_it(real_data_dir):
    """Found as a user: windows of the real trench below its closed end (126 rows from
    row 110, 116 and 122) took a bright septum between two cells for the closed end; the
    start dropped the rows above it and the fit drew one 11.9 um cell for two and a half
    (reduced chi-square 76). Rows above a closed end show the device alone, with little
    structure across them; a window whose first rows show the trench's walls has its
    closed end above the image. The whole trench keeps its closed end, 22 rows down,
    and so do windows that start just above it."""
    import tifffile

    from napari_symbac.fit.start import start_scene

    image = tifffile.imread(real_data_dir / "ecoli_100x_oil_exponential.tiff").astype(float)
    microscope = Microscope(pixel_size_um=0.065)
    trench = start_scene(image, microscope)[2]
    assert round(trench.top_um / 0.065) == 22
    for row in (110, 116, 122):
        window = image[row : row + 126, 2:45]
        assert start_scene(window, microscope)[2].top_um < 0
    # windows that keep the closed end 6 to 2 rows below their top keep it in view
    # (the rows its own halo reaches above it are not judged)
    for row in (16, 20):
        assert 0 <= start_scene(image[row:, 2:45], microscope)[2].top_um < 0.5
    fit = fit_scene(image[110:236, 2:45], microscope, RenderSettings(), None)
    assert len(fit.cells) == 2
    assert fit.objective_after < 15  # 11.9; 76 with the septum taken for the closed end
