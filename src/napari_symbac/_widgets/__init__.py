"""napari dock widgets (magicgui containers), registered by ``napari.yaml``.

Each widget is a thin layer over a public headless call; the core never imports this
package, and importing it needs the ``[gui]`` extra.
"""
