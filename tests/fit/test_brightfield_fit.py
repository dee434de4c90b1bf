"""Bright field: the lens term of cells out of focus, fitted on rendered and real fields."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import tifffile
from _fit_synthetic import BRIGHTFIELD_TRUTH, make_brightfield_field

from napari_symbac.fit import fit_scene


@pytest.fixture(scope="module")
def field():
    return make_brightfield_field()


def test_the_fit_recovers_cells_and_the_lens_term(field):
    """Started from its own segmentation and an in-focus kernel (kappa 0), the fit finds
    the four cells, their width and length, and the lens term's kappa."""
    start = dataclasses.replace(
        BRIGHTFIELD_TRUTH, defocus_contrast_um2=0.0, defocus_sigma_um=0.0, cell_intensity=2000.0
    )
    fitted = fit_scene(field.image.astype(float), field.microscope, start, field.camera,
                       geometry="open")  # fmt: skip
    assert len(fitted.cells.ids) == 4
    order = np.argsort(fitted.cells.y_um * 10 + fitted.cells.x_um)
    want = np.argsort(field.cells.y_um * 10 + field.cells.x_um)
    np.testing.assert_allclose(fitted.cells.width_um[order], 0.9, atol=0.03)
    np.testing.assert_allclose(
        fitted.cells.length_um[order], field.cells.length_um[want], atol=0.08
    )
    assert fitted.render.defocus_contrast_um2 == pytest.approx(0.015, rel=0.1)
    assert fitted.render.cell_intensity == pytest.approx(2500.0, rel=0.02)
    assert fitted.render.media_intensity == pytest.approx(2600.0, rel=0.01)
    assert fitted.objective_after < 1.3
    k = fitted.parameter_names.index("lens_amplitude_adu_um2")
    lens, se = fitted.parameters[k], fitted.standard_errors[k]
    assert lens == pytest.approx(0.015 * 2600.0, abs=4 * se)


def test_the_lens_column_is_the_difference_of_renders(field):
    """The fourth design column times kappa I_m is what the forward model adds for the
    lens term (render with kappa minus render without)."""
    from napari_symbac.optics import ForwardModel

    r = dataclasses.replace(BRIGHTFIELD_TRUTH, noise_model="none")
    with_lens = ForwardModel(field.microscope, r).render_clean(field.scene)
    without = ForwardModel(
        field.microscope, dataclasses.replace(r, defocus_contrast_um2=0.0)
    ).render_clean(field.scene)
    lens = with_lens - without
    assert abs(float(lens.sum())) < 1e-2 * float(np.abs(lens).sum())  # light moved, not made
    # a cell's centre line is brighter, its rim darker (kappa > 0)
    rows, cols = np.nonzero(field.scene.camera_labels() > 0)
    assert lens[rows, cols].mean() > 0
    doubled = ForwardModel(
        field.microscope, dataclasses.replace(r, defocus_contrast_um2=0.03)
    ).render_clean(field.scene)
    np.testing.assert_allclose(doubled - without, 2 * lens, atol=1e-3 * np.abs(lens).max())


def _cli_fit(tmp_path, image, *args) -> tuple[int, str]:
    from napari_symbac.cli import main

    tmp_path.mkdir(exist_ok=True)
    microscope = tmp_path / "bf.yaml"
    microscope.write_text(
        "pixel_size_um: 0.08\nnumerical_aperture: 1.4\nwavelength_um: 0.55\n"
        "modality: brightfield\n"
    )
    out = tmp_path / "out"
    code = main(["fit", str(image), "--microscope", str(microscope), "--out", str(out), *args])
    return code, out


def test_colicoords_crop_in_bright_field_is_one_cell_with_a_bright_centre(
    tmp_path, real_data_dir
):
    """Found as a user: ColiCoords' crop 01 in bright field (a dark rim round a bright
    centre) fitted as phase contrast was a trench with walls, a 2.2 um wide cell and
    exit 0. As bright field, from its own start or its mask, it is one cell ~1.1 um
    wide whose lens term makes the bright centre (kappa > 0), the report says so."""
    import yaml

    folder = real_data_dir / "colicoords" / "01"
    widths = []
    for masks in ((), ("--masks", str(folder / "binary.tif"))):
        code, out = _cli_fit(tmp_path / str(len(masks)), folder / "brightfield.tif", *masks)
        assert code == 0
        cells = yaml.safe_load((out / "settings.yaml").read_text())
        render = cells["render"]
        assert render["defocus_contrast_um2"] > 0.005
        assert render["cell_intensity"] <= render["media_intensity"]  # it absorbs
        report = (out / "report.txt").read_text()
        assert "cells fitted: 1\n" in report
        assert "modality             brightfield (" in report
        assert "lens_amplitude_adu_um2" in report
        widths.append(cells["simulation"]["cell_width_um"])
    assert widths == pytest.approx([1.08, 1.08], abs=0.1)


def test_a_fluorescence_field_is_not_fitted_as_bright_field(tmp_path, real_data_dir, capsys):
    image = real_data_dir / "colicoords" / "test_data" / "ds1" / "fluorescence" / "00001.tif"
    code, out = _cli_fit(tmp_path, image)
    assert code == 2
    assert not out.exists()
    error = capsys.readouterr().err
    assert "does not look like bright field" in error
    assert "--modality fluorescence" in error


def test_a_bright_field_series_is_fitted_jointly(tmp_path, real_data_dir):
    """Two frames of the crop (the second moved by a pixel): fitted jointly with the lens
    amplitude per frame. Found as a user: the flattened crop's frames give no pooled
    photon transfer, and the command ended in a traceback (for phase contrast too)."""
    import json

    crop = tifffile.imread(real_data_dir / "colicoords" / "01" / "brightfield.tif")
    series = tmp_path / "series.tif"
    tifffile.imwrite(series, np.stack([crop, np.roll(crop, 1, axis=1)]))
    code, out = _cli_fit(tmp_path, series, "--frames", "0-1")
    assert code == 0
    assert json.loads((out / "series.json").read_text())["camera"] is None  # per frame
    for frame in ("frame_0000", "frame_0001"):
        report = (out / frame / "report.txt").read_text()
        assert "cells fitted: 1\n" in report
        assert "lens_amplitude_adu_um2" in report


def test_a_lens_term_no_cell_out_of_focus_gives_is_a_problem():
    """|kappa| <= 2.1 lambda^2 / (pi NA^2) (two depths of field, a cell's phase at most
    2.1 rad): 0.103 um^2 at 0.55 um and NA 1.4."""
    from napari_symbac.fit.report import lens_problem
    from napari_symbac.settings import Microscope

    microscope = Microscope(
        pixel_size_um=0.08, numerical_aperture=1.4, wavelength_um=0.55, modality="brightfield"
    )
    fitted = dataclasses.replace(BRIGHTFIELD_TRUTH, defocus_contrast_um2=0.015)
    assert lens_problem(fitted, microscope) is None
    beyond = dataclasses.replace(BRIGHTFIELD_TRUTH, defocus_contrast_um2=-0.2)
    problem = lens_problem(beyond, microscope)
    assert problem.startswith("the lens term, kappa = -0.2 um^2, is beyond")
    assert "<= 0.103 um^2" in problem
    phase = dataclasses.replace(microscope, modality="phase")
    assert lens_problem(beyond, phase) is None


def test_a_camera_that_cannot_be_measured_is_said_once_in_each_interface(
    tmp_path, real_data_dir
):
    """Found as an API user: ColiCoords ds1's bright field near clipping (64567-65535
    ADU) came back with a "camera" of 0.001 ADU/e- and 48629 e- read noise, and no
    word: the noise is then a constant fitted to the residual. The Python result says
    so; the CLI's report says it once, in its own terms (--camera)."""
    from scipy import ndimage

    from napari_symbac.fit.scene_fit import UNMEASURED_CAMERA
    from napari_symbac.settings import Microscope, RenderSettings

    folder = real_data_dir / "colicoords" / "test_data" / "ds1"
    crop = (slice(90, 200), slice(60, 320))
    image = tifffile.imread(folder / "brightfield" / "00001.tif")[crop]
    binary = tifffile.imread(folder / "binary" / "00001_Probabilities_filtered.tif")[crop]
    masks = ndimage.label(binary > 0)[0]
    microscope = Microscope(pixel_size_um=0.08, modality="brightfield")
    fit = fit_scene(image, microscope, RenderSettings(), geometry="open", masks=masks)
    said = [w for w in fit.warnings if w.startswith(UNMEASURED_CAMERA)]
    assert len(said) == 1
    assert "camera=Camera(" in said[0]
    assert len(fit.cells) == 4

    tifffile.imwrite(tmp_path / "bf.tif", image)
    tifffile.imwrite(tmp_path / "masks.tif", masks.astype(np.uint16))
    code, out = _cli_fit(
        tmp_path / "cli", tmp_path / "bf.tif", "--masks", str(tmp_path / "masks.tif"),
        "--geometry", "field",
    )
    report = (out / "report.txt").read_text()
    assert code == 0
    assert UNMEASURED_CAMERA not in report
    assert "camera=Camera(" not in report
    assert "--camera" in report
