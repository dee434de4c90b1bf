"""Dock widget: the whole workflow in one dock, one tab per step.

Four docked widgets stacked vertically need more than 2000 px of height; in tabs,
each in a scroll area, the dock fits a 1366 x 768 laptop screen beside the canvas.
``napari -w napari-symbac`` opens this widget (the manifest lists it first).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from qtpy.QtCore import QEvent, QObject
from qtpy.QtWidgets import QFrame, QScrollArea, QStyle, QTabWidget, QWidget

from napari_symbac._widgets.diagnose import DiagnoseWidget
from napari_symbac._widgets.export import ExportWidget
from napari_symbac._widgets.real_image import RealImageWidget
from napari_symbac._widgets.simulate import SimulateWidget
from napari_symbac._widgets.tune import TuneWidget

if TYPE_CHECKING:
    import napari

__all__ = ["WorkflowWidget"]

#: Tab titles, in the order of the workflow.
TABS = ("1 Recording", "2 Simulate", "3 Tune + fit", "4 Diagnose", "5 Export")


class WorkflowWidget(QTabWidget):
    """Recording -> Simulate -> Tune + fit -> Diagnose -> Export, as tabs of one dock widget.

    The five step widgets are the ones napari also offers separately; they share the
    recording through its layer's metadata, so a tab can be used alone.
    """

    def __init__(self, viewer: napari.viewer.Viewer):
        super().__init__()
        self.setObjectName("symbac_workflow")
        self.real_image = RealImageWidget(viewer)
        self.simulate = SimulateWidget(viewer)
        self.tune = TuneWidget(viewer)
        self.diagnose = DiagnoseWidget(viewer)
        self.export = ExportWidget(viewer)
        tips = (
            "Open your recording, set its pixel size and microscope, paint and measure classes.",
            "Simulate growth with your recording's microscope and render it.",
            "Tune optics and noise live; Auto-fit the scene to your recording.",
            "Find, name and fit what the model misses in your recording; "
            "the updated settings go to Export.",
            "Export a training dataset with the tuned settings.",
        )
        for title, tip, widget in zip(
            TABS, tips, (self.real_image, self.simulate, self.tune, self.diagnose, self.export)
        ):
            area = QScrollArea()
            area.setWidgetResizable(True)
            area.setFrameShape(QFrame.Shape.NoFrame)
            _rows_at_the_top(widget.native)
            area.setWidget(widget.native)
            widget.native.installEventFilter(self)
            index = self.addTab(area, title)
            self.setTabToolTip(index, tip)
        self._fit_widest_step()

    def _fit_widest_step(self) -> None:
        """Never narrower than the widest step: no sideways scrolling, no cut labels."""
        widest = max(
            self.widget(i).widget().minimumSizeHint().width() for i in range(self.count())
        )
        scrollbar = self.style().pixelMetric(QStyle.PixelMetric.PM_ScrollBarExtent)
        if self.minimumWidth() != widest + scrollbar + 16:
            self.setMinimumWidth(widest + scrollbar + 16)

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:
        """Follow a step that grows after a run (fit readouts, tables, reports)."""
        if event.type() == QEvent.Type.LayoutRequest:
            self._fit_widest_step()
        return super().eventFilter(watched, event)


def _rows_at_the_top(step: QWidget) -> None:
    """Keep the rows of ``step`` at its top, the room left below them.

    The scroll area stretches its widget to the tab's height; a step stretched so spread
    its spare height between its rows (found as a user: gaps of ~40 px between the
    *Recording* tab's rows at 1366 x 768). A stretch after the last row takes it
    (magicgui inserts rows by their index, before it).
    """
    layout = step.layout()
    if layout is not None and hasattr(layout, "addStretch"):
        layout.addStretch(1)
