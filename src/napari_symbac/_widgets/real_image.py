"""Dock widget: load a real recording, paint cell / media / device classes, measure them.

Headless equivalents: :func:`napari_symbac.io.read_recording` and
:func:`napari_symbac.fit.class_statistics`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from magicgui.widgets import ComboBox, Container, FileEdit, FloatSpinBox, Label, PushButton

from napari_symbac.fit import CLASS_VALUES, class_statistics

if TYPE_CHECKING:
    import napari

__all__ = ["CLASS_COLOURS", "RealImageWidget", "class_layer_name"]

#: Colours of the painted classes (RGBA), shared by the layer and the legend.
CLASS_COLOURS = {"cell": "#ff5a36", "media": "#2e9bff", "device": "#b0b0b0"}


def class_layer_name(image_name: str) -> str:
    """Name of the class-labels layer painted on ``image_name``."""
    return f"{image_name} classes"


class RealImageWidget(Container):
    """Choose a real image, paint rough class labels on it, and measure the classes.

    * **image**: any image layer, or open a TIFF (pixel size read from its metadata).
    * **Paint classes**: adds a labels layer with the classes cell (1), media (2) and
      device (3), in fixed colours, in paint mode with the cell class selected.
    * **Measure**: mean and variance of each painted class (eq. 2).
    """

    def __init__(self, viewer: napari.viewer.Viewer):
        super().__init__(name="symbac_real_image")
        self.viewer = viewer
        self.image = ComboBox(name="image", label="real image", choices=self._image_layers)
        self.file = FileEdit(name="file", label="or open", filter="*.tif *.tiff", mode="r")
        self.pixel_size = FloatSpinBox(
            name="pixel_size_um",
            label="pixel size (um)",
            value=0.065,
            min=0.001,
            max=10,
            step=0.001,
        )
        self.modality = ComboBox(
            name="modality", label="modality", choices=["phase", "fluorescence"]
        )
        self.paint_button = PushButton(name="paint", text="Paint classes")
        self.measure_button = PushButton(name="measure", text="Measure classes")
        legend = " ".join(
            f"<b style='color:{colour}'>{value} {name}</b>"
            for (name, colour), value in zip(CLASS_COLOURS.items(), CLASS_VALUES.values())
        )
        self.legend = Label(name="legend", value=legend)
        self.result = Label(name="result", value="")
        self.extend(
            [
                self.image,
                self.file,
                self.pixel_size,
                self.modality,
                self.paint_button,
                self.legend,
                self.measure_button,
                self.result,
            ]
        )
        self.file.changed.connect(self._open_file)
        self.image.changed.connect(self._prefill_pixel_size)
        self.paint_button.changed.connect(self.paint)
        self.measure_button.changed.connect(self.measure)
        viewer.layers.events.inserted.connect(self.image.reset_choices)
        viewer.layers.events.removed.connect(self.image.reset_choices)
        self.statistics = None
        self._prefill_pixel_size()

    def _image_layers(self, _widget=None) -> list:
        from napari.layers import Image

        return [layer for layer in self.viewer.layers if isinstance(layer, Image)]

    def _open_file(self) -> None:
        from napari_symbac.io import read_recording

        path = self.file.value
        if not path or not path.is_file():
            return
        try:
            recording = read_recording(path)
        except (ValueError, OSError) as err:
            self.result.value = f"Cannot open {path.name}: {err}"
            return
        layer = self.viewer.add_image(
            recording.data,
            name=recording.name,
            metadata={"pixel_size_um": recording.pixel_size_um, "modality": recording.modality},
        )
        self.image.value = layer

    def _prefill_pixel_size(self, _value=None) -> None:
        """Fill pixel size and modality from the layer's metadata (or its scale)."""
        layer = self.image.value
        if layer is None:
            return
        if layer.metadata.get("modality") in self.modality.choices:
            self.modality.value = layer.metadata["modality"]
        pixel = layer.metadata.get("pixel_size_um")
        if not pixel and layer.scale[-1] != 1:  # a layer already scaled to micrometres
            pixel = float(layer.scale[-1])
        if pixel:
            self.pixel_size.value = pixel

    def paint(self) -> None:
        """Add (or select) the class-labels layer for the chosen image, ready to paint."""
        from napari.utils.colormaps import DirectLabelColormap

        layer = self.image.value
        if layer is None:
            self.result.value = "Open or choose an image first"
            return
        name = class_layer_name(layer.name)
        if name not in self.viewer.layers:
            colours = {None: "transparent", 0: "transparent"}
            colours.update({CLASS_VALUES[cls]: colour for cls, colour in CLASS_COLOURS.items()})
            labels = self.viewer.add_labels(
                np.zeros(layer.data.shape, np.uint8),
                name=name,
                scale=layer.scale,
                translate=layer.translate,
                opacity=0.5,
                colormap=DirectLabelColormap(color_dict=colours),
            )
            labels.brush_size = 5
        labels = self.viewer.layers[name]
        labels.selected_label = CLASS_VALUES["cell"]
        labels.mode = "paint"
        self.viewer.layers.selection.active = labels

    def measure(self) -> None:
        """Mean and variance of each painted class (eq. 2), shown in the widget."""
        layer = self.image.value
        if layer is None or class_layer_name(layer.name) not in self.viewer.layers:
            self.result.value = "Paint classes first"
            return
        labels = self.viewer.layers[class_layer_name(layer.name)].data
        try:
            self.statistics = class_statistics(layer.data, labels, required=("cell", "media"))
        except ValueError as err:
            self.result.value = str(err)
            return
        self.result.value = "<br>".join(
            f"{name}: mean {stat.mean:.1f}, sd {np.sqrt(stat.variance):.1f} ({stat.n_pixels} px)"
            for name, stat in self.statistics.items()
        )
