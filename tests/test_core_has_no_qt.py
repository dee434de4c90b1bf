"""The core library and the CLI must not import Qt or napari."""

from __future__ import annotations

import subprocess
import sys

CHECK = """
import sys
import napari_symbac, napari_symbac.cli, napari_symbac.pipeline, napari_symbac.demo
import napari_symbac.sim, napari_symbac.scene, napari_symbac.optics
import napari_symbac.fit, napari_symbac.diagnose, napari_symbac.export, napari_symbac.bench.rows
napari_symbac.cli.build_parser()
bad = sorted(m for m in sys.modules
             if m.split('.')[0] in {'napari', 'qtpy', 'PyQt5', 'PyQt6', 'PySide2', 'PySide6',
                                     'magicgui', 'superqt', 'vispy'})
print(','.join(bad))
"""


def test_core_imports_no_gui_toolkit():
    result = subprocess.run(
        [sys.executable, "-c", CHECK], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == ""


LAZY = """
import sys
import napari_symbac
assert 'napari_symbac.fit' not in sys.modules  # nothing loaded by the bare import
print(napari_symbac.fit.fit_scene.__module__, napari_symbac.export.export_dataset.__name__)
print(sorted(set(napari_symbac.__all__) - {'__version__'}))
"""


def test_the_subpackages_load_as_the_docs_name_them():
    """Found as a user: ``import napari_symbac`` then ``napari_symbac.fit.fit_scene``, as
    the docs write it, was an AttributeError until ``import napari_symbac.fit``."""
    result = subprocess.run(
        [sys.executable, "-c", LAZY], capture_output=True, text=True, check=True
    )
    first, second = result.stdout.strip().splitlines()
    assert first == "napari_symbac.fit.scene_fit export_dataset"
    assert second == str(
        ["calibrate", "diagnose", "export", "fit", "optics", "scene", "sim"]
    )
