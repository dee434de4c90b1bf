"""Each catalogued effect hidden below the noise: signature found, parameter recovered."""

from __future__ import annotations

import numpy as np
import pytest

from napari_symbac.diagnose.concealed import make_case
from napari_symbac.diagnose.effects import CATALOGUE
from napari_symbac.diagnose.effects.fixed_pattern_noise import FixedPatternNoise, column_basis
from napari_symbac.diagnose.effects.uneven_illumination import UnevenIllumination
from napari_symbac.diagnose.model import fit_model, geometry_from_labels
from napari_symbac.diagnose.run import _params
from napari_symbac.diagnose.selection import ModelSpec, rank

CASES = [
    ("uneven_illumination", "phase"),
    ("halo", "phase"),
    ("defocus_gradient", "fluorescence"),
    ("camera_noise", "phase"),
    ("photobleaching", "fluorescence"),
    ("stage_drift", "fluorescence"),
    ("cell_intensity_variability", "fluorescence"),
    ("background_texture", "phase"),
    ("cell_curvature", "fluorescence"),
    ("stray_light", "phase"),
    ("fixed_pattern_noise", "phase"),
    ("saturation", "phase"),
    ("envelope_stain", "fluorescence"),
    # bright field: the lens term is a column of the base design, and these act beside it
    ("background_texture", "brightfield"),
    ("cell_intensity_variability", "brightfield"),
    ("cell_curvature", "brightfield"),
    ("defocus_gradient", "brightfield"),
]


def _setup(name: str, modality: str, seed: int):
    geometry = "field" if name == "background_texture" else "trench"
    case = make_case(name, modality=modality, geometry=geometry, fraction_of_sd=0.8, seed=seed)
    y = case.images.astype(float) - case.design.camera.baseline_adu
    valid = np.ones(y.shape, bool)
    geo = case.design.geometry
    pool = [
        cls(geo)
        for cls in CATALOGUE.values()
        if modality in cls.modalities and (not cls.needs_series or geo.shape[0] >= 3)
    ]
    return case, y, valid, pool


@pytest.mark.parametrize(("name", "modality"), CASES)
def test_signature_detected_and_parameter_recovered(name, modality):
    case, y, valid, pool = _setup(name, modality, seed=11)
    current = fit_model(case.design, y, valid)
    ranked = rank(pool, case.design, y, current, valid)
    best, test = ranked[0]
    assert best.name == name, [(e.name, round(t.evidence, 1)) for e, t in ranked[:3]]
    assert test.evidence > -np.log10(0.01 / len(pool))
    spec = ModelSpec().with_effect(best, y)
    fitted = spec.fit(case.design, y, valid)
    params = _params(best, fitted, spec, case.design)
    value = params["clip_level_adu"] if name == "saturation" else best.magnitude(params)
    assert value == pytest.approx(case.true_magnitude, rel=0.35), params


def test_no_effect_control_flags_nothing():
    for seed in (21, 22, 23):
        _, _, valid, pool = _setup("halo", "phase", seed)
        control = make_case(None, modality="phase", fraction_of_sd=0.8, seed=seed)
        y = control.images.astype(float) - control.design.camera.baseline_adu
        current = fit_model(control.design, y, valid)
        ranked = rank(pool, control.design, y, current, valid)
        assert ranked[0][1].evidence < -np.log10(0.01 / len(pool)), ranked[0]


@pytest.mark.parametrize(("cols", "pixel_um", "n_modes"), [(46, 0.065, 42), (256, 0.08, 228)])
def test_column_offsets_leave_smooth_trends_to_illumination_and_texture(cols, pixel_um, n_modes):
    """Column offsets are the columns' modes shorter than the texture's 1.5 um: a smooth
    profile (what a cells' misfit cancelled by the texture looked like on a real field)
    is out of their reach, independent column offsets nearly all within it."""
    basis = column_basis(cols, pixel_um)
    assert basis.shape == (cols, n_modes)
    np.testing.assert_allclose(basis.T @ basis, np.eye(n_modes), atol=1e-12)
    x = np.linspace(-1, 1, cols)
    waves = [np.cos(2 * np.pi * np.arange(cols) * pixel_um / 3.0 + phase) for phase in (0, 1, 2)]
    for smooth in (np.ones(cols), x, x**2, *waves):  # the waves: 3 um, twice the texture's 1.5
        kept = basis @ (basis.T @ smooth)
        assert np.linalg.norm(kept) < 0.25 * np.linalg.norm(smooth)
    stripes = np.random.default_rng(0).normal(size=(200, cols))
    kept = stripes @ basis
    assert np.sum(kept**2) / np.sum(stripes**2) > 0.8


def _trench_labels(rows: int, first_row: int) -> np.ndarray:
    """``(1, rows, 46)`` labels: cells 15 px wide down the middle from ``first_row``."""
    labels = np.zeros((1, rows, 46), np.int64)
    for k, top in enumerate(range(first_row, rows, 40)):
        labels[0, top : top + 37, 16:31] = k + 1
    return labels


def test_column_offsets_are_confirmed_only_where_they_fit_the_columns_far_from_cells():
    """A camera's offsets act on every pixel of a column, so they also shift the column
    means far from the cells; offsets that only the cells' pixels ask for (a misfit of the
    cells or the trench walls taken as columns) do not, and are refused with the reason.
    Columns with too few far pixels cannot judge them."""
    labels = _trench_labels(256, 30)
    geometry = geometry_from_labels(labels, (labels > 0).astype(float), 0.065, "phase")
    effect = FixedPatternNoise(geometry)
    theta = np.random.default_rng(0).normal(0.0, 20.0, effect.n_params())
    offsets = effect.column_offsets(theta)
    far = geometry.distance_px >= 8
    assert far.sum(axis=(0, 1)).min() >= 8  # the 30 rows above the first cell
    valid = np.ones(labels.shape, bool)
    noise = np.random.default_rng(1).normal(0.0, 5.0, labels.shape)
    mean = np.full(labels.shape, 1000.0)  # the offsets' check does not use it
    # the fitted mean holds the offsets: a camera's columns leave the noise behind
    camera = effect.confirm(theta, noise, valid, mean)
    assert camera.confirmed, camera.reason
    assert camera.reason.startswith("column offsets confirmed far from cells")
    numbers = camera.numbers
    assert numbers["far_column_misfit_with_offsets_adu2"] < 0.2 * numbers[
        "far_column_misfit_without_offsets_adu2"
    ]
    # the same offsets where only the pixels near cells had them: far from cells the
    # fit put offsets the data lack, and subtracting them raises the misfit there
    misfit = effect.confirm(
        theta, noise - np.where(far, offsets[None, None, :], 0.0), valid, mean
    )
    assert not misfit.confirmed
    assert misfit.reason.startswith("column offsets do not match the columns far from cells")
    assert misfit.reason.endswith("cell/trench misfit, not the camera")
    assert misfit.numbers["far_column_misfit_with_offsets_adu2"] > misfit.numbers[
        "far_column_misfit_without_offsets_adu2"
    ]
    # cells from the closed end down: the middle columns have no far pixel to judge by
    crowded = _trench_labels(256, 2)
    geometry = geometry_from_labels(crowded, (crowded > 0).astype(float), 0.065, "phase")
    middle = np.zeros(46)
    middle[12:35] = 30.0 * (-1.0) ** np.arange(23)
    theta = column_basis(46, 0.065).T @ middle
    unjudged = FixedPatternNoise(geometry).confirm(theta, noise, valid, mean)
    assert not unjudged.confirmed
    assert unjudged.reason.startswith("column offsets cannot be confirmed: only ")


def test_illumination_is_confirmed_only_where_the_pixels_far_from_cells_show_it():
    """The light multiplies every pixel, so a true illumination field shows in the
    PDMS and media far from the cells as it does in the cells; a surface that only the
    cells ask for (their misfit taken as a light field) is not there, and is refused
    with the reason. A background too dim for the surface to show cannot judge it."""
    labels = _trench_labels(256, 30)
    geometry = geometry_from_labels(labels, (labels > 0).astype(float), 0.065, "phase")
    effect = UnevenIllumination(geometry)
    theta = np.array([0.05, 0.08, 0.10, -0.06, 0.04])  # peak to peak about 0.4
    surface = effect.mean(theta, np.ones(labels.shape), None, geometry)
    cells = geometry.distance_px < 0
    base = np.where(cells, 2000.0, 1000.0)  # dark media and PDMS, bright cells
    lit = base * surface  # the fitted mean, the surface in it
    valid = np.ones(labels.shape, bool)
    noise = np.random.default_rng(1).normal(0.0, 30.0, labels.shape)
    # the light: the fitted surface leaves the noise behind, far from cells too
    light = effect.confirm(theta, noise, valid, lit)
    assert light.confirmed, light.reason
    assert light.reason.startswith("illumination confirmed far from cells")
    numbers = light.numbers
    assert numbers["tiles_judged"] >= 12
    assert numbers["far_disagreement_beyond_noise_adu"] < 0.2 * numbers["far_change_rms_adu"]
    for term, value in zip(("x", "y", "x^2", "y^2", "xy"), theta):
        assert numbers[f"far_surface_{term}"] == pytest.approx(value, abs=0.01)
    # the cells' misfit: the recording is brighter or darker only in and near the cells,
    # where the fit put a surface; far from them it is flat, as the fit without a surface
    near = geometry.distance_px < 4
    recording = np.where(near, lit, base) + noise
    misfit = effect.confirm(theta, recording - lit, valid, lit)
    assert not misfit.confirmed
    assert misfit.reason.startswith("illumination does not match the pixels far from cells")
    assert misfit.reason.endswith("cell/trench misfit, not the light")
    numbers = misfit.numbers
    assert numbers["far_disagreement_beyond_noise_adu"] > 0.5 * numbers["far_change_rms_adu"]
    assert abs(numbers["far_surface_x^2"]) < 0.01  # the far pixels ask for no bow
    # a background near zero (a background-subtracted fluorescence field): the surface
    # changes the far pixels by less than their noise, and cannot be confirmed there
    dim = np.where(cells, 2000.0, 2.0) * surface
    unjudged = effect.confirm(theta, noise, valid, dim)
    assert not unjudged.confirmed
    assert unjudged.reason.startswith("illumination cannot be confirmed: its change at the pixels")
    # cells from the closed end down, nearly wall to wall: too few tiles far from cells
    packed = np.zeros((1, 256, 46), np.int64)
    packed[0, 2:, 2:44] = 1
    geometry = geometry_from_labels(packed, (packed > 0).astype(float), 0.065, "phase")
    crowded = UnevenIllumination(geometry).confirm(theta, noise, valid, lit)
    assert not crowded.confirmed
    assert crowded.reason.startswith("illumination cannot be confirmed: only 0 of 192 tiles")


def test_illumination_that_varies_more_than_twofold_across_the_window_is_refused():
    """Found as a user: cells cut at a 256 px window's lower edge were taken for light
    varying 210 % (peak to peak) across ColiCoords ds2 00066's window, confirmed far from
    the cells, and drawn into the dataset. A lamp varies by tens of % across a field of
    view; more than twofold across a window is refused with the reason."""
    labels = _trench_labels(256, 30)
    geometry = geometry_from_labels(labels, (labels > 0).astype(float), 0.065, "phase")
    effect = UnevenIllumination(geometry)
    valid = np.ones(labels.shape, bool)
    noise = np.random.default_rng(1).normal(0.0, 30.0, labels.shape)
    base = np.where(geometry.distance_px < 0, 2000.0, 1000.0)
    gentle, steep = [0.0, 0.30, 0.0, 0.0, 0.0], [0.0, 0.45, 0.0, 0.0, 0.0]  # 1.9, 2.6-fold
    for theta, confirmed in ((gentle, True), (steep, False)):
        lit = base * effect.mean(np.array(theta), np.ones(labels.shape), None, geometry)
        check = effect.confirm(np.array(theta), noise, valid, lit)
        assert check.confirmed == confirmed, check.reason
    assert check.reason.startswith("illumination refused: the fitted light varies 2.6-fold")


def test_cells_brightening_with_time_are_no_bleaching():
    """Found as a user: a synthetic trench series, flat in time, was "bleached" at
    -0.0033 per frame and accepted. The concealed bleaching series played backwards (the
    cells brightening) fits a rate of 0, forwards its true rate."""
    from napari_symbac.diagnose.effects.photobleaching import Photobleaching

    case = make_case("photobleaching", modality="fluorescence", fraction_of_sd=0.8, seed=11)
    rates = []
    for images in (case.images, case.images[::-1]):
        y = images.astype(float) - case.design.camera.baseline_adu
        effect = Photobleaching(case.design.geometry)
        spec = ModelSpec().with_effect(effect, y)
        fitted = spec.fit(case.design, y, np.ones(y.shape, bool))
        rates.append(_params(effect, fitted, spec, case.design)["rate_per_frame"])
    assert rates[0] == pytest.approx(case.true_magnitude, rel=0.35)
    assert rates[1] == 0.0


def test_a_ring_or_haze_found_is_said_by_its_sign():
    """Found as a user: report.txt gave "halo ... amplitude_adu: -173" and left the sign
    to decode; an accepted halo or stray light is now said in words, as the fit found it."""
    from napari_symbac.diagnose.effects import CATALOGUE

    halo, stray = CATALOGUE["halo"], CATALOGUE["stray_light"]
    assert halo.finding({"amplitude_adu": -173.0}).startswith("a weaker halo than the model's")
    assert halo.finding({"amplitude_adu": 50.0}).startswith("a stronger halo")
    said = stray.finding({"amplitude_adu": -196.0})
    assert "(-196 ADU where cells fill the surroundings)" in said
    assert stray.finding({"amplitude_adu": -196.0}).startswith("the cells darken")


@pytest.mark.parametrize("name", ["halo", "stray_light"])
def test_a_cell_pattern_draws_a_cell_the_same_whatever_else_the_frame_holds(name):
    """A ring or haze was scaled to each image's own peak: the exported frame of one cell
    got the haze the fit had measured around a trench full of them, and a series' frames
    were scaled together in the fit but each alone in the export. Now the pattern around
    a cell is the same alone, beside a crowd 10 um away and in any frame of a stack; a
    straight edge's ring and a wide region's haze are 1 (the amplitude's meaning)."""
    from napari_symbac.diagnose.effects import CATALOGUE

    pattern = CATALOGUE[name].pattern
    px = 0.1
    alone = np.zeros((1, 300, 300))
    alone[0, 40:70, 45:55] = 1.0  # a 1 x 3 um cell
    crowd = alone.copy()
    crowd[0, 150:300, 150:300] = 1.0  # 15 x 15 um of cells, 10 um away
    stack = np.concatenate([crowd, alone])
    near = (slice(None), slice(20, 90), slice(25, 75))
    drawn = pattern(alone, px)[near]
    np.testing.assert_allclose(pattern(crowd, px)[near], drawn, atol=1e-6)
    np.testing.assert_allclose(pattern(stack, px)[1:][near], drawn, atol=1e-12)
    wide = pattern(crowd, px)[0]
    if name == "stray_light":
        assert wide[225, 225] == pytest.approx(1.0, abs=1e-3)  # 7.5 um inside the crowd
        assert drawn.max() == pytest.approx(0.18, abs=0.01)  # one cell alone
    else:
        # beside the crowd's edge (the 0.1 um Gaussian sampled at 0.1 um: 2 % high)
        assert wide[225, 100:150].max() == pytest.approx(1.0, abs=0.03)
