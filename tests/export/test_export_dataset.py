"""ExportSettings and the real simulate -> draw -> render item generator."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import tifffile
import yaml
from _export_synthetic import tree_digest

from napari_symbac.export import (
    ExportSettings,
    Randomisation,
    Range,
    export_dataset,
    load_export_settings,
    regenerate,
    run_export,
)
from napari_symbac.export.dataset import PipelineSource, _simulation, sequence_of, split_of
from napari_symbac.settings import (
    PipelineSettings,
    SimulationSettings,
    TrenchGeometry,
    from_dict,
    save_settings,
    to_dict,
)

PIPELINE = PipelineSettings(simulation=SimulationSettings(n_frames=10))


def _settings(**changes) -> ExportSettings:
    base = ExportSettings(
        n_items=5,
        formats=["tiff", "stardist"],
        seed=7,
        val_fraction=0.4,
        first_frame=5,
        pipeline=PIPELINE,
    )
    return dataclasses.replace(base, **changes)


def test_settings_validation_messages():
    with pytest.raises(ValueError, match="kind to 'timeseries'"):
        ExportSettings(formats=["ctc"])
    with pytest.raises(ValueError, match="unknown format"):
        ExportSettings(formats=["tiff", "hdf5"])
    with pytest.raises(ValueError, match="val_fraction"):
        ExportSettings(val_fraction=1.0)
    with pytest.raises(ValueError, match="first_frame"):
        ExportSettings(first_frame=60)
    # found as a user: a time series (which holds every frame) shortened below the
    # default export's first_frame was refused for it; one of 1 frame had no tracks
    short = PipelineSettings(simulation=SimulationSettings(n_frames=20))
    series = ExportSettings(pipeline=short, kind="timeseries", first_frame=23, n_items=1)
    assert series.n_images == 20
    with pytest.raises(ValueError, match="first_frame=23 must be in"):
        ExportSettings(pipeline=short, kind="frames", first_frame=23)
    single = PipelineSettings(simulation=SimulationSettings(n_frames=1))
    with pytest.raises(ValueError, match=r"needs pipeline\.simulation\.n_frames >= 2"):
        ExportSettings(pipeline=single, kind="timeseries", n_items=1)
    with pytest.raises(ValueError, match="must not exceed"):
        Range(2.0, 1.0)
    # from a file, named by where it sits (found as a user: "Range low=2.0 must not
    # exceed high=1.0" from a file of six ranges)
    with pytest.raises(ValueError, match=r"^ExportSettings\.randomise\.noise_scale: Range low"):
        from_dict(ExportSettings, {"randomise": {"noise_scale": {"low": 2, "high": 1}}})
    assert ExportSettings(formats="tiff, coco").formats == ["tiff", "coco"]


def test_settings_yaml_round_trip(tmp_path):
    settings = _settings(
        kind="timeseries",
        formats=["ctc", "trackmate"],
        randomise=Randomisation(noise_scale=Range(0.5, 2.0)),
    )
    path = save_settings(settings, tmp_path / "export.yaml")
    assert load_export_settings(path) == settings
    # the CLI prints defaults with yaml.safe_dump(to_dict(...))
    text = yaml.safe_dump(to_dict(ExportSettings()))
    assert "formats" in text
    # a partial file takes defaults for the rest
    partial = tmp_path / "partial.yaml"
    partial.write_text(
        "n_items: 3\nformats: [omnipose]\nrandomise:\n  noise_scale: {low: 1, high: 1}\n"
    )
    loaded = load_export_settings(partial)
    assert loaded.n_items == 3
    assert loaded.randomise.noise_scale == Range(1.0, 1.0)
    assert loaded.pipeline == PipelineSettings()


def test_split_is_exact_and_seeded():
    settings = _settings(n_items=50, val_fraction=0.2)
    val = [u for u in range(50) if split_of(settings, u) == "val"]
    assert len(val) == 10
    other = [
        u
        for u in range(50)
        if split_of(_settings(n_items=50, val_fraction=0.2, seed=8), u) == "val"
    ]
    assert other != val


def test_sequences_are_numbered_per_split():
    """CTC needs 01, 02, ... in each split: sequence_of ranks a unit within its split."""
    settings = _settings(n_items=40, val_fraction=0.3)
    for split in ("train", "val"):
        units = [u for u in range(40) if split_of(settings, u) == split]
        assert [sequence_of(settings, u) for u in units] == list(range(len(units)))


@pytest.fixture(scope="module")
def frames_export(tmp_path_factory):
    out = tmp_path_factory.mktemp("real")
    report = export_dataset(_settings(), out, workers=1)
    assert report.complete
    return out


def test_real_frames_round_trip(frames_export):
    manifest = json.loads((frames_export / "manifest.json").read_text())
    assert manifest["status"] == "complete"
    assert manifest["settings"]["seed"] == 7
    entries = manifest["items"]
    assert [e["split"] for e in entries].count("val") == 2
    cell_intensities = set()
    for entry in entries:
        images = tifffile.imread(frames_export / entry["files"]["tiff"][0])
        labels = tifffile.imread(frames_export / entry["files"]["tiff"][1])
        semantic = tifffile.imread(frames_export / entry["files"]["tiff"][2])
        masks = tifffile.imread(frames_export / entry["files"]["stardist"][1])
        assert images.dtype == np.uint16
        assert images.shape == labels.shape == tuple(entry["shape"])
        assert labels.dtype == np.uint16
        np.testing.assert_array_equal(masks, labels)
        assert set(np.unique(semantic)) <= {0, 1}
        assert not np.any((semantic > 0) & (labels == 0))
        assert 5 <= entry["params"]["frame"] < 10
        base = PIPELINE.render.cell_intensity
        assert 0.85 * base <= entry["params"]["render.cell_intensity"] <= 1.15 * base
        cell_intensities.add(entry["params"]["render.cell_intensity"])
        # cells are brighter or darker than media: the image is not flat
        assert images.std() > 0
    assert len(cell_intensities) == len(entries)  # every item draws its own


@pytest.mark.parametrize(
    ("kind", "formats"),
    [
        ("frames", ["tiff", "png", "delta", "omnipose", "stardist", "coco", "ome-zarr"]),
        ("timeseries", ["ctc", "trackmate", "ome-zarr"]),
    ],
)
def test_every_file_written_is_named_in_the_manifest(tmp_path, kind, formats):
    """docs/export.md: every file of the dataset is named in the manifest (found as a
    user: the OME-Zarr stores' .zattrs, .zgroup and .zarray were not, so a copy made
    from the manifest could not be opened)."""
    settings = _settings(n_items=3 if kind == "frames" else 2, kind=kind, formats=formats)
    if kind == "timeseries":
        settings = dataclasses.replace(settings, first_frame=0)
    out = tmp_path / "ds"
    assert export_dataset(settings, out, workers=1).complete
    manifest = json.loads((out / "manifest.json").read_text())
    named = {"manifest.json"} | {f for files in manifest["files"].values() for f in files}
    for entry in manifest["items"]:
        named |= {f for files in entry["files"].values() for f in files}
    written = {
        str(path.relative_to(out))
        for path in out.rglob("*")
        if path.is_file() and path.parent.name != "manifest_items"
    }
    assert written - named == set()
    assert {f for f in named if not (out / f).is_file()} == set()


def test_regenerate_is_bit_identical(frames_export):
    entry = json.loads((frames_export / "manifest_items" / "000003.json").read_text())
    item = regenerate(frames_export, "000003")
    np.testing.assert_array_equal(
        item.image, tifffile.imread(frames_export / entry["files"]["tiff"][0])
    )
    np.testing.assert_array_equal(
        item.labels, tifffile.imread(frames_export / entry["files"]["tiff"][1])
    )
    assert dict(item.params) == entry["params"]
    with pytest.raises(KeyError, match="items are named '000000' to '000004' \\(text"):
        regenerate(frames_export, 3)  # found as an API user: no hint of the names


def test_seed_controls_the_files(tmp_path, frames_export):
    export_dataset(_settings(), tmp_path / "same", workers=1)
    assert tree_digest(tmp_path / "same") == tree_digest(frames_export)
    export_dataset(_settings(seed=8), tmp_path / "other", workers=1)
    a = tifffile.imread(frames_export / "tiff" / "train" / "images" / "000000.tif")
    other = tmp_path / "other" / "tiff"
    b = tifffile.imread(next(other.rglob("000000.tif")))
    assert a.shape == b.shape
    assert not np.array_equal(a, b)


def test_real_pipeline_parallel_equals_serial(tmp_path, frames_export):
    """A LocalCluster of two processes renders the same bytes as the serial run.

    The workers receive the simulation this process made for ``frames_export`` with the
    pickled source, and render every item (nothing is written here meanwhile).
    """
    settings = _settings()
    report = run_export(
        PipelineSource(settings), tmp_path, settings.formats, workers=2, overlap_start=False
    )
    assert report.workers == 2
    assert tree_digest(tmp_path) == tree_digest(frames_export)


def test_pickled_source_carries_its_simulations():
    """A worker given the source renders without simulating again; the same items."""
    import pickle

    from napari_symbac.export import dataset

    settings = _settings(n_items=2)
    made = PipelineSource(settings).make_unit(1)[0]
    shipped = pickle.dumps(PipelineSource(settings))
    key = dataset._simulation_key(settings.pipeline, settings.seed, 0)
    simulation = dataset._SIMULATIONS.pop(key)
    received = pickle.loads(shipped)
    assert dataset._SIMULATIONS[key] is not simulation  # installed from the pickle
    again = received.make_unit(1)[0]
    assert np.array_equal(again.image, made.image)
    assert np.array_equal(again.labels, made.labels)
    assert received.backend == "scipy"
    on_torch = PipelineSource(settings, backend="torch")
    assert on_torch.backend.startswith("torch:")
    assert pickle.loads(pickle.dumps(on_torch)).backend == on_torch.backend  # as asked


def test_real_time_series_tracking_ground_truth(tmp_path):
    settings = _settings(
        n_items=1, kind="timeseries", formats=["ctc", "delta"], val_fraction=0.0
    )
    report = export_dataset(settings, tmp_path, workers=1)
    assert report.n_items == 10
    simulation = _simulation(settings.pipeline, settings.seed, 0)
    table = np.loadtxt(
        tmp_path / "ctc" / "train" / "01_GT" / "TRA" / "man_track.txt", dtype=int, ndmin=2
    )
    assert len(table) >= 2
    for label, begin, end, parent in table:
        record = simulation.lineage[label]
        assert parent == record.parent_id
        assert record.birth_frame <= begin <= end <= record.end_frame
        if parent:
            parent_end = table[table[:, 0] == parent][0, 2]
            assert parent_end < begin
        mask = tifffile.imread(
            tmp_path / "ctc" / "train" / "01_GT" / "TRA" / f"man_track{begin:03d}.tif"
        )
        assert label in mask
    # DeLTA tracking: one sample per cell of every frame but the last
    entries = json.loads((tmp_path / "manifest.json").read_text())["items"]
    samples = sorted(p.name for p in (tmp_path / "delta" / "train" / "tracking" / "seg").iterdir())
    assert len(samples) == sum(len(e["objects"]) for e in entries[:-1])
    assert samples[0].startswith("s0000_t0001_cell")
    # the first frame of every series is its own item with the series' drawn parameters
    items = PipelineSource(settings).make_unit(0)
    assert [it.frame for it in items] == list(range(10))
    assert len({json.dumps(dict(it.params) | {"frame": 0}) for it in items}) == 1


def test_exposure_scales_all_light_and_keeps_default_streams():
    plain, doubled = Randomisation(), Randomisation(exposure_scale=Range(2.0, 2.0))
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    a, b = plain.draw(rng_a, PIPELINE), doubled.draw(rng_b, PIPELINE)
    for key in ("render.cell_intensity", "render.media_intensity", "render.device_intensity"):
        assert b[key] == pytest.approx(2.0 * a[key])
    # the camera noise is not scaled: the signal-to-noise changes with the exposure
    assert b["camera.dark_noise_e"] == a["camera.dark_noise_e"]
    # a fixed exposure draws no number: the item's later draws are those of before
    assert rng_a.random() == rng_b.random()


def test_exposure_is_drawn_log_uniformly_between_its_bounds():
    varied = Randomisation(exposure_scale=Range(0.5, 2.0))
    rng, fixed_rng = np.random.default_rng(11), np.random.default_rng(11)
    ratios = []
    for _ in range(400):
        v = varied.draw(rng, PIPELINE)
        f = Randomisation().draw(fixed_rng, PIPELINE)
        fixed_rng.random()  # keep the two streams in step (the varied one drew once more)
        ratios.append(v["render.cell_intensity"] / f["render.cell_intensity"])
    ratios = np.array(ratios)
    assert ratios.min() >= 0.5
    assert ratios.max() <= 2.0
    # log-uniform: as many below the geometric mean (1) as above, a quarter below 1/sqrt 2
    assert 0.4 < (ratios < 1.0).mean() < 0.6
    assert 0.18 < (ratios < 2**-0.5).mean() < 0.32
    with pytest.raises(ValueError, match=r"exposure_scale .*low must be above 0"):
        Randomisation(exposure_scale=Range(0.0, 2.0))


def test_a_pipeline_file_is_the_pipeline_of_the_default_export(tmp_path):
    """Found as a user: `export --config` with the settings.yaml `fit` wrote (a pipeline
    file) was refused; it is read as the pipeline of the default export. A file that is
    neither keeps the export's own message."""
    from napari_symbac.export import ExportSettings, load_export_settings
    from napari_symbac.settings import PipelineSettings, RenderSettings, save_settings

    pipeline = PipelineSettings(render=RenderSettings(cell_intensity=1234.0))
    path = save_settings(pipeline, tmp_path / "settings.yaml")
    default = ExportSettings(pipeline=pipeline, first_frame=23)  # the trench full
    assert load_export_settings(path) == default
    (tmp_path / "bad.yaml").write_text("n_itemz: 3\n")
    with pytest.raises(ValueError, match=r"n_itemz.*ExportSettings"):
        load_export_settings(tmp_path / "bad.yaml")
    # a pipeline file's own mistake is named, not taken for a wrong ExportSettings file
    (tmp_path / "typo.yaml").write_text("render:\n  cell_intensty: 3\n")
    with pytest.raises(ValueError, match="cell_intensty") as raised:
        load_export_settings(tmp_path / "typo.yaml")
    assert "ExportSettings" not in str(raised.value)


def test_the_default_export_of_a_pad_draws_from_several_simulations(tmp_path):
    """Found exporting a fitted ColiCoords field (a pad of one frame, its 8 lone cells):
    every image of the one default simulation showed the same cells in the same places.
    A pad's default export draws from up to 16 simulations, each its own layout; a
    trench keeps one, whose frames differ."""
    from napari_symbac.export import ExportSettings, export_of, load_export_settings
    from napari_symbac.export.dataset import PAD_SIMULATIONS

    pad = PipelineSettings(simulation=SimulationSettings(geometry="agar_pad", n_frames=1))
    path = save_settings(pad, tmp_path / "settings.yaml")
    assert load_export_settings(path) == ExportSettings(pipeline=pad, n_simulations=16)
    assert export_of(pad, n_items=3).n_simulations == 3
    assert export_of(pad, n_simulations=2).n_simulations == 2  # given: kept
    assert PAD_SIMULATIONS == 16
    assert export_of(PipelineSettings()).n_simulations == 1  # the default trench
    # the images differ: their cells are in other places
    settings = export_of(pad, n_items=2, formats=["tiff"], val_fraction=0.0)
    source = PipelineSource(settings)
    first, second = (source.make_unit(unit)[0] for unit in (0, 1))
    assert first.labels.shape == second.labels.shape
    assert not np.array_equal(first.labels > 0, second.labels > 0)


@pytest.mark.parametrize(
    "simulation",
    [
        SimulationSettings(),
        SimulationSettings(n_founders=2),
        SimulationSettings(growth_model="adder", added_length_um=2.0),
        # the trench `fit` writes for the SyMBac trench: 15.85 um, cells dividing at 6.15 um
        SimulationSettings(trench=TrenchGeometry(length_um=15.85), cell_max_length_um=6.15),
    ],
)
def test_the_default_export_of_a_trench_draws_full_trenches(simulation):
    """Found exporting a fit of the SyMBac trench, full of cells: frames were drawn from
    the whole run, and a quarter showed one or two cells in an empty trench. The default
    export starts where the simulation holds nearly as many cells as it keeps after."""
    from napari_symbac.export import export_of
    from napari_symbac.sim import simulate

    counts = np.array([len(f.ids) for f in simulate(simulation).frames])
    first = export_of(PipelineSettings(simulation=simulation)).first_frame
    full = np.median(counts[first:])
    assert 0 < first <= simulation.n_frames // 2
    assert counts[first:].min() >= 0.7 * full  # no frame of a trench still filling
    assert counts[first // 2] < 0.7 * full  # half-way there the trench was filling
    assert export_of(PipelineSettings(simulation=simulation), first_frame=0).first_frame == 0


def test_the_default_export_of_a_fitted_colony_draws_grown_colonies():
    """Found exporting after Auto-fit of a 182-cell Omnipose colony: images of 1, 21,
    229 and 81 cells, from the whole run of a colony grown from one founder. A pad's
    default export draws from its colonies' last doubling."""
    from napari_symbac.calibrate.core import pad_layout
    from napari_symbac.export import export_of
    from napari_symbac.sim import simulate

    cells = {"division_length_um": 3.5, "width_um": 1.0}  # the defaults'
    fields, _ = pad_layout((400, 400), 0.07, n_colonies=1, cells_per_colony=100, **cells)
    simulation = SimulationSettings(**fields, seed=1)
    counts = np.array([len(f.ids) for f in simulate(simulation).frames])
    first = export_of(PipelineSettings(simulation=simulation)).first_frame
    assert counts[first:].min() >= 0.4 * counts[-1]
    assert counts[first // 2] < 0.2 * counts[-1]  # the whole run held far fewer
    assert export_of(PipelineSettings(simulation=simulation), first_frame=0).first_frame == 0
