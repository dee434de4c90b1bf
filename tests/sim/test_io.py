"""Saving and loading simulations; clear errors for bad input."""

from __future__ import annotations

import json
import os
import shutil
import stat

import numpy as np
import pytest

from napari_symbac.settings import SimulationSettings, TrenchGeometry
from napari_symbac.sim import FORMAT_VERSION, load_simulation, save_simulation, simulate


@pytest.fixture(scope="module")
def sim():
    return simulate(SimulationSettings(n_frames=40, lysis_p=0.01, do_transformation=True, seed=9))


def test_round_trip_is_exact(sim, tmp_path):
    out = save_simulation(sim, tmp_path / "run")
    assert sorted(p.name for p in out.iterdir()) == ["frames.npz", "lineage.npz", "simulation.json"]
    meta = json.loads((out / "simulation.json").read_text())
    assert meta["format_version"] == FORMAT_VERSION
    assert meta["settings"]["n_frames"] == 40
    loaded = load_simulation(out)
    assert loaded == sim
    assert loaded.frames[5].x_um.tobytes() == sim.frames[5].x_um.tobytes()
    assert loaded.lineage[1].curvature == sim.lineage[1].curvature
    # saving again replaces the previous simulation, leaving no temporary folders
    save_simulation(sim, out)
    assert load_simulation(out) == sim
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_loads_files_from_older_versions(sim, tmp_path):
    out = save_simulation(sim, tmp_path / "run")
    meta = json.loads((out / "simulation.json").read_text())
    # an older version knew fewer settings: they take their defaults
    for name in ("jitter_um", "angle_jitter_rad", "geometry", "agar_pad", "outline"):
        del meta["settings"][name]
    del meta["walls_um"]
    (out / "simulation.json").write_text(json.dumps(meta))
    loaded = load_simulation(out)
    assert loaded.frames == sim.frames
    assert loaded.lineage == sim.lineage
    assert loaded.settings == sim.settings


def test_newer_format_is_refused_with_advice(sim, tmp_path):
    out = save_simulation(sim, tmp_path / "run")
    meta = json.loads((out / "simulation.json").read_text())
    meta["format_version"] = FORMAT_VERSION + 1
    (out / "simulation.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="upgrade napari-symbac"):
        load_simulation(out)


@pytest.mark.parametrize(
    "damage",
    ["truncate_frames", "drop_lineage", "bad_json", "bad_offsets", "bad_settings", "garbage"],
)
def test_corrupt_simulation_gives_clear_error(sim, tmp_path, damage):
    out = save_simulation(sim, tmp_path / "run")
    if damage == "truncate_frames":
        data = (out / "frames.npz").read_bytes()
        (out / "frames.npz").write_bytes(data[: len(data) // 2])
    elif damage == "drop_lineage":
        (out / "lineage.npz").unlink()
    elif damage == "bad_json":
        (out / "simulation.json").write_text("{not json")
    elif damage == "bad_offsets":
        with np.load(out / "frames.npz") as data:
            arrays = dict(data)
        arrays["offsets"] = arrays["offsets"][:-3]
        np.savez(out / "frames.npz", **arrays)
    elif damage == "bad_settings":
        meta = json.loads((out / "simulation.json").read_text())
        meta["settings"]["cell_width_um"] = -1
        (out / "simulation.json").write_text(json.dumps(meta))
    elif damage == "garbage":  # bytes numpy reads as neither zip nor array
        (out / "frames.npz").write_bytes(b"\x00not an array file" * 64)
    with pytest.raises(ValueError, match="not a readable saved simulation") as caught:
        load_simulation(out)
    # numpy's advice to load unsafely is not passed on (found as a user)
    assert "allow_pickle" not in str(caught.value)


def test_missing_simulation(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"nothing does not exist"):
        load_simulation(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match=r"simulation\.json is missing"):
        load_simulation(tmp_path / "empty")


def test_never_overwrites_foreign_folders(sim, tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "holiday.jpg").write_bytes(b"precious")
    with pytest.raises(FileExistsError, match="holds other files"):
        save_simulation(sim, folder)
    assert [p.name for p in folder.iterdir()] == ["holiday.jpg"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos"]


def test_unwritable_save_dir_fails_before_simulating(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    settings = SimulationSettings(n_frames=5, save_dir=str(blocker / "sim"))
    calls = []
    with pytest.raises(OSError, match="save_dir"):
        simulate(settings, progress=lambda *a: calls.append(a))
    assert calls == []  # failed before any work


def test_save_dir_saves_the_run(tmp_path):
    settings = SimulationSettings(n_frames=5, save_dir=str(tmp_path / "auto"))
    result = simulate(settings)
    assert load_simulation(tmp_path / "auto") == result


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"n_frames": 0}, "n_frames"),
        ({"cell_width_um": 1.5}, "width_um"),
        ({"max_length_var_um2": -0.1}, "max_length_var_um2"),
        ({"width_var_um2": -0.1}, "width_var_um2"),
        ({"phys_iters": 0}, "phys_iters"),
        ({"lysis_p": 1.5}, "lysis_p"),
        ({"geometry": "moon"}, "geometry"),
        ({"geometry": "outline"}, "outline"),
        ({"n_founders": 0}, "n_founders"),
        ({"septum_sd": 0.3}, "septum_sd"),
    ],
)
def test_bad_settings_name_the_field(changes, field):
    with pytest.raises(ValueError, match=field):
        SimulationSettings(**changes)


def test_too_many_founders_for_the_trench():
    settings = SimulationSettings(n_founders=8, trench=TrenchGeometry(length_um=10.0))
    with pytest.raises(ValueError, match="n_founders"):
        simulate(settings)


def test_missing_dxf_file(tmp_path):
    from napari_symbac.settings import OutlineGeometry

    settings = SimulationSettings(
        geometry="outline", outline=OutlineGeometry(dxf_path=str(tmp_path / "none.dxf"))
    )
    with pytest.raises(OSError, match="dxf_path"):
        simulate(settings)
    shutil.rmtree(tmp_path, ignore_errors=True)


def test_a_foreign_save_dir_fails_before_simulating(tmp_path):
    """Found as a user: `simulate --out` a folder of notes ran all its frames, then refused."""
    folder = tmp_path / "notes"
    folder.mkdir()
    (folder / "notes.txt").write_text("x")
    calls = []
    with pytest.raises(FileExistsError, match="holds other files"):
        simulate(
            SimulationSettings(n_frames=5, save_dir=str(folder)),
            progress=lambda *a: calls.append(a),
        )
    assert calls == []  # failed before any work
    assert [p.name for p in folder.iterdir()] == ["notes.txt"]


def test_a_saved_simulation_has_the_mode_of_any_new_folder(sim, tmp_path):
    """Found as a user: the folder kept tempfile's 0o700, unreadable to colleagues."""
    old = os.umask(0o022)
    try:
        path = save_simulation(sim, tmp_path / "shared")
        save_simulation(sim, tmp_path / "shared")  # replaced: the same mode
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o755
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shared"]
