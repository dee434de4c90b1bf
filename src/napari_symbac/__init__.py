"""napari-symbac: synthetic micrographs of bacteria with perfect ground truth.

The core library (``sim``, ``scene``, ``optics``, ``fit``, ``diagnose``, ``export``)
never imports Qt or napari; the napari widgets live in ``napari_symbac._widgets``.
Its subpackages load on first use: ``import napari_symbac`` then
``napari_symbac.fit.fit_scene`` works as the docs write it (found as a user: an
``AttributeError`` until ``import napari_symbac.fit``).
"""

import importlib

__version__ = "0.1.0"

#: The core's subpackages, imported when first named as attributes of the package.
SUBPACKAGES = ("calibrate", "diagnose", "export", "fit", "optics", "scene", "sim")

__all__ = ["__version__", *SUBPACKAGES]


def __getattr__(name: str):
    """Import a core subpackage on first use (PEP 562)."""
    if name in SUBPACKAGES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
