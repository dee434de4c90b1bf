"""Move the tuning sliders as a user would and watch the preview layer follow."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")

from napari_symbac._widgets.simulate import (
    RESULT_IMAGE_LAYER,
    RESULT_LABELS_LAYER,
    SYMBAC_METADATA_KEY,
    SimulateWidget,
)
from napari_symbac._widgets.tune import TuneWidget


@pytest.fixture
def rendered(make_napari_viewer, qtbot):
    viewer = make_napari_viewer()
    simulate = SimulateWidget(viewer)
    tune = TuneWidget(viewer)
    viewer.window.add_dock_widget(simulate)
    viewer.window.add_dock_widget(tune)
    simulate.form.n_frames.value = 3
    simulate.run_button.native.click()
    qtbot.waitUntil(lambda: RESULT_LABELS_LAYER in viewer.layers, timeout=120_000)
    qtbot.waitUntil(lambda: simulate.worker is None, timeout=10_000)
    return viewer, tune


def test_slider_moves_change_the_preview(rendered):
    viewer, tune = rendered
    assert tune.source.value is viewer.layers[RESULT_IMAGE_LAYER]
    layer = viewer.layers[RESULT_IMAGE_LAYER]
    labels = viewer.layers[RESULT_LABELS_LAYER].data
    frame = tune._current_frame()
    cells = labels[frame] > 0
    before = layer.data[frame][cells].mean()
    tune.sliders["cell_intensity"].value = tune.sliders["cell_intensity"].value + 3000
    after = layer.data[frame][cells].mean()
    assert after > before + 1500
    settings = layer.metadata[SYMBAC_METADATA_KEY]["settings"]
    assert settings.render.cell_intensity == pytest.approx(tune.sliders["cell_intensity"].value)


def test_other_frames_update_when_shown(rendered):
    viewer, tune = rendered
    layer = viewer.layers[RESULT_IMAGE_LAYER]
    viewer.dims.set_current_step(0, 0)
    old_last = layer.data[2].copy()
    tune.sliders["media_intensity"].value = tune.sliders["media_intensity"].value + 4000
    np.testing.assert_array_equal(layer.data[2], old_last)  # not re-rendered yet
    viewer.dims.set_current_step(0, 2)
    assert layer.data[2].mean() > old_last.mean() + 1000


def test_invalid_value_is_reported(rendered):
    _viewer, tune = rendered
    tune.sliders["apodisation_sigma_um"].min = 0.05
    tune.sliders["apodisation_sigma_um"].value = 0.06
    assert "Not applied" in tune.status.value


def test_auto_fit_recovers_intensities(rendered, qtbot):
    from napari_symbac._widgets.real_image import class_layer_name
    from napari_symbac.fit.parameters import scene_classes

    viewer, tune = rendered
    frame = tune._current_frame()
    scene = tune.preview.scene(frame)
    truth = {"cell_intensity": 2100.0, "media_intensity": 3300.0, "device_intensity": 700.0}
    start = {name: tune.sliders[name].value for name in truth}
    tune.preview.update(**truth)
    real = tune.preview.frame(frame).astype("uint16")
    tune.preview.update(**start)
    viewer.add_image(real, name="real")
    viewer.add_labels(scene_classes(scene).astype("uint8"), name=class_layer_name("real"))
    tune.reference.value = viewer.layers["real"]
    tune.fit_button.native.click()
    qtbot.waitUntil(lambda: tune.fit_worker is None, timeout=300_000)
    assert tune.fit_result is not None, tune.status.value
    for name, value in truth.items():
        assert tune.sliders[name].value == pytest.approx(value, rel=0.05), name
    assert tune.fit_result.objective_after < tune.fit_result.objective_before
    assert tune.terms_table.shape[0] == len(tune.fit_result.terms)
    assert "Fitted in" in tune.status.value


def test_auto_fit_needs_painted_classes(rendered):
    viewer, tune = rendered
    viewer.add_image(viewer.layers[RESULT_IMAGE_LAYER].data[0], name="plain")
    tune.reference.value = viewer.layers["plain"]
    tune.fit_button.native.click()
    assert "Paint classes on plain first" in tune.status.value
    assert tune.fit_worker is None


def test_match_noise_measures_the_real_image(rendered):
    import numpy as np

    viewer, tune = rendered
    rng = np.random.default_rng(1)
    _, x = np.mgrid[:120, :60]
    real = (2000 + 5 * x + rng.normal(0, 35.0, x.shape)).astype(np.float32)
    viewer.add_image(real, name="noisy real")
    tune.reference.value = viewer.layers["noisy real"]
    tune.match_noise.value = True
    assert tune.noise_model.value == "gaussian"
    assert tune.sliders["gaussian_noise_sd_adu"].value == pytest.approx(35.0, rel=0.08)
    assert tune.preview.render_settings.gaussian_noise_sd_adu == pytest.approx(35.0, rel=0.08)
    assert "Noise matched" in tune.status.value
