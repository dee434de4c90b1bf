"""Objective terms (eq. 20 and better): zero for a match, sensitive to what matters."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.fit import CLASS_VALUES, TERM_NAMES, objective_terms, scene_classes
from napari_symbac.optics import ForwardModel


def test_identical_images_score_zero(truth):
    image = truth.image.astype(float)
    terms = objective_terms(image, image, scene_classes(truth.scene), variance=100.0)
    assert set(terms) == set(TERM_NAMES)
    for name, value in terms.items():
        assert value == pytest.approx(0.0, abs=1e-12), name


def test_eq20_is_the_sum_of_relative_class_mean_errors():
    real = np.full((20, 30), 100.0)
    real[:, 20:] = 300.0
    real[5:15, 5:10] = 50.0
    classes = np.full(real.shape, CLASS_VALUES["media"])
    classes[:, 20:] = CLASS_VALUES["device"]
    classes[5:15, 5:10] = CLASS_VALUES["cell"]
    synthetic = real * 1.1  # every class 10 % too bright
    terms = objective_terms(synthetic, real, classes, terms=("eq20", "class_stats"))
    assert terms["eq20"] == pytest.approx(0.3)
    assert terms["class_stats"] == pytest.approx(3 * 0.01)


def test_blur_shows_in_spectrum_and_edge_profile_but_not_in_eq20(truth):
    blurred = ForwardModel(
        truth.microscope,
        truth.render.__class__(**{**truth.render.__dict__, "defocus_sigma_um": 0.35}),
        truth.camera,
    ).render(truth.scene, np.random.default_rng(2))
    classes = scene_classes(truth.scene)
    same = objective_terms(
        ForwardModel(truth.microscope, truth.render, truth.camera).render(
            truth.scene, np.random.default_rng(3)
        ),
        truth.image,
        classes,
    )
    other = objective_terms(blurred, truth.image, classes)
    assert other["edge_profile"] > 5 * same["edge_profile"]
    assert other["spectrum"] > 5 * same["spectrum"]
    assert other["pixel"] > 2 * same["pixel"]


def test_different_shapes_need_a_pair_of_class_maps(truth):
    classes = scene_classes(truth.scene)
    crop = truth.image[:100]
    with pytest.raises(ValueError, match="pair"):
        objective_terms(crop, truth.image, classes)
    terms = objective_terms(crop, truth.image, (classes, classes[:100]))
    assert "pixel" not in terms
    assert terms["histogram"] < 0.2
    with pytest.raises(ValueError, match="pixel term"):
        objective_terms(crop, truth.image, (classes, classes[:100]), terms=("pixel",))


def test_unknown_term_and_bad_masks_are_rejected(truth):
    classes = scene_classes(truth.scene)
    with pytest.raises(ValueError, match="unknown objective term"):
        objective_terms(truth.image, truth.image, classes, terms=("ssim",))
    with pytest.raises(ValueError, match="do not match"):
        objective_terms(truth.image, truth.image, classes[:10])
    with pytest.raises(ValueError, match="unknown class"):
        objective_terms(truth.image, truth.image, {"cells": classes == 1})


def test_rough_strokes_give_every_term_a_value(truth):
    """Strokes that never meet a cell's edge: no term is nan, and each still compares."""
    strokes = np.zeros(truth.image.shape, np.int64)
    strokes[20:24, 18:22] = CLASS_VALUES["cell"]  # interior of a cell, far from media
    strokes[60:62, 24:25] = CLASS_VALUES["media"]
    names = tuple(t for t in TERM_NAMES if t != "pixel")
    same = objective_terms(truth.image, truth.image, strokes, terms=names)
    assert all(np.isfinite(v) for v in same.values()), same
    assert same["edge_profile"] == 0
    assert same["eq20"] == 0
    flatter = truth.image.astype(float) * 0.5 + float(truth.image.mean()) * 0.5
    other = objective_terms(flatter, truth.image, strokes, terms=names)
    assert all(np.isfinite(v) for v in other.values()), other
    assert other["edge_profile"] == pytest.approx(0.5, rel=1e-6)  # half the contrast
