"""The figures of ``napari-symbac diagnose`` can be read: a heading, titled panels
enlarged from a thin trench, colour bars with units, curves on labelled axes."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np

from napari_symbac.diagnose.figures import write_figures
from napari_symbac.diagnose.run import Diagnosis, EffectResult
from napari_symbac.diagnose.statistics import Mismatch
from napari_symbac.figure_layout import line_plot, map_scale

ROWS, COLS = 256, 46  # the trench of ecoli_100x_oil_exponential.tiff


def ramp_length(picture: np.ndarray, top: tuple, bottom: tuple) -> int:
    """Longest run down a column whose colour goes steadily from ``top`` to ``bottom``
    (a colour bar; channels equal at both ends, such as green through white, may do
    anything); 0 when there is none."""
    top, bottom = np.array(top), np.array(bottom)
    channels = top != bottom
    sign = np.sign(bottom - top)[channels]
    best = 0
    for x in range(picture.shape[1]):
        column = picture[:, x].astype(int)
        steady = np.all(np.diff(column[:, channels], axis=0) * sign >= 0, axis=1)
        start = 0
        for i in range(len(steady) + 1):
            if i < len(steady) and steady[i]:
                continue
            # rows start..i form a steady run
            if (
                i > start
                and np.abs(column[start] - top).max() <= 10
                and np.abs(column[i] - bottom).max() <= 10
            ):
                best = max(best, i - start + 1)
            start = i + 1
    return best


def longest_black_run(picture: np.ndarray) -> int:
    """Longest horizontal run of black pixels (an axis of a plot)."""
    best = 0
    for row in (picture == 0).all(axis=-1):
        edges = np.diff(np.concatenate([[0], row.astype(int), [0]]))
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        if starts.size:
            best = max(best, int((ends - starts).max()))
    return best


def has_heading(picture: np.ndarray) -> bool:
    """Dark text on white in the top 40 rows (not an image running to the edge)."""
    strip = picture[:40].min(axis=-1)
    return bool((strip >= 250).mean() > 0.8 and (strip < 80).any())


def _diagnosis(seed: int = 0) -> Diagnosis:
    rng = np.random.default_rng(seed)
    shape = (1, ROWS, COLS)
    gradient = np.linspace(-1.0, 1.0, ROWS)[None, :, None] * np.ones(shape)
    rows_profile = tuple(np.linspace(-1, 1, ROWS) + rng.normal(0, 0.3, ROWS))
    return Diagnosis(
        base_fit={"metric": "reduced chi-square", "value": 18.8, "held_out": 28.66},
        final_fit={"metric": "reduced chi-square", "value": 14.4, "held_out": 24.33},
        mismatches=[
            Mismatch(
                "along the field (rows)", "chi2 of line means (256 dof)", 3e4, 4000.0, rows_profile
            ),
            Mismatch(
                "distance to the nearest cell edge (-6..20 px)",
                "chi2 of 1-px ring means (27 dof)",
                5e3,
                600.0,
                tuple(np.sin(np.arange(27) / 4.0)),
            ),
        ],
        effects=[
            EffectResult(
                name="uneven_illumination",
                explanation="The illumination is brighter on one side of the field.",
                signature="",
                evidence=892.0,
                dof=3,
                accepted=True,
                params={},
                held_out_before=28.66,
                held_out_after=26.34,
                effect_map=300.0 * gradient,
            ),
            EffectResult("halo", "A halo.", "", 1.0, 1, False, {}, 26.3, 26.3),
        ],
        residual_before=rng.normal(size=shape) + 3 * gradient,
        residual_after=rng.normal(size=shape),
        final_model=None,
    )


def test_trench_figures_are_large_titled_and_have_colour_bars(tmp_path):
    image = 500 + 100 * np.random.default_rng(1).random((ROWS, COLS))
    written = write_figures(_diagnosis(), image, tmp_path, name="trench.tif")
    assert written == ["residuals.png", "effect_uneven_illumination.png"]
    residuals = iio.imread(tmp_path / "residuals.png")
    scale = map_scale((ROWS, COLS))
    assert ROWS * scale >= 400
    # three maps side by side, each enlarged, under a heading and titles
    assert residuals.shape[0] >= ROWS * scale + 60
    assert residuals.shape[1] >= 3 * COLS * scale
    assert has_heading(residuals)
    # the residuals' diverging bar (red at the top) and the image's grey bar (ADU)
    assert ramp_length(residuals, (255, 0, 0), (0, 0, 255)) >= 0.95 * ROWS * scale
    assert ramp_length(residuals, (255, 255, 255), (0, 0, 0)) >= 0.95 * ROWS * scale

    effect = iio.imread(tmp_path / "effect_uneven_illumination.png")
    assert effect.shape[0] >= ROWS * scale
    assert has_heading(effect)
    assert ramp_length(effect, (255, 0, 0), (0, 0, 255)) >= 0.95 * ROWS * scale
    assert longest_black_run(effect) >= 400  # the plot's frame: a curve on axes


def test_figures_are_deterministic(tmp_path):
    image = 500 + 100 * np.random.default_rng(1).random((ROWS, COLS))
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        write_figures(_diagnosis(), image, tmp_path / name)
    for file in ("residuals.png", "effect_uneven_illumination.png"):
        assert (tmp_path / "a" / file).read_bytes() == (tmp_path / "b" / file).read_bytes()


def test_a_wide_field_is_drawn_one_map_below_the_other(tmp_path):
    diagnosis = _diagnosis()
    diagnosis.residual_before = diagnosis.residual_before.transpose(0, 2, 1)
    diagnosis.residual_after = diagnosis.residual_after.transpose(0, 2, 1)
    for effect in diagnosis.effects:
        if effect.effect_map is not None:
            effect.effect_map = effect.effect_map.transpose(0, 2, 1)
    image = np.ones((COLS, ROWS)) * np.arange(ROWS)
    write_figures(diagnosis, image, tmp_path)
    residuals = iio.imread(tmp_path / "residuals.png")
    scale = map_scale((COLS, ROWS))
    assert residuals.shape[0] >= 3 * COLS * scale
    assert residuals.shape[1] < 2 * ROWS * scale


def test_line_plot_has_axes_and_room_for_labels():
    values = np.sin(np.arange(30) / 3)
    plot = line_plot(
        values, x=np.arange(30) - 6.0, xlabel="distance (px)", ylabel="mean residual (s.d.)"
    )
    assert plot.shape[0] > 260
    assert plot.shape[1] > 420
    assert longest_black_run(plot) >= 420
    # tick labels left of the frame and the turned y label: dark pixels there
    assert (plot[:, :40].min(axis=-1) < 80).any()
