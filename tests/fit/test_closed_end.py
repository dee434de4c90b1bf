"""The fit chooses the trench's closed end, square or round, by the image."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from _fit_synthetic import PIXEL_UM, TRENCH, TRUTH, make_cells

from napari_symbac.fit import fit_scene
from napari_symbac.optics import ForwardModel
from napari_symbac.scene import draw_scene
from napari_symbac.settings import Camera, Microscope


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
