"""napari-symbac: synthetic micrographs of bacteria with perfect ground truth.

The core library (``sim``, ``scene``, ``optics``, ``fit``, ``diagnose``, ``export``)
never imports Qt or napari; the napari widgets live in ``napari_symbac._widgets``.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
