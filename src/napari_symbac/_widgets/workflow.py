"""Dock widget: the whole workflow in one dock, one tab per step; and each step alone.

Four docked widgets stacked vertically need more than 2000 px of height; in tabs,
each in a scroll area, the dock fits a 1366 x 768 laptop screen beside the canvas.
``napari -w napari-symbac`` opens this widget (the manifest lists it first).

A step opened alone (*Plugins > SyMBac synthetic micrographs*) scrolls in its dock the
same way (:class:`SimulateDock` and its siblings): napari docks a widget at its full
height, and Simulate's form alone asks for over 1000 px.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from qtpy.QtCore import QEvent, QObject, Qt
from qtpy.QtWidgets import QFrame, QScrollArea, QStyle, QTabWidget, QWidget

from napari_symbac._widgets._links import release_with_dock
from napari_symbac._widgets._recording import is_recording
from napari_symbac._widgets.calibrate import CalibrateWidget
from napari_symbac._widgets.diagnose import DiagnoseWidget
from napari_symbac._widgets.export import ExportWidget
from napari_symbac._widgets.real_image import RealImageWidget
from napari_symbac._widgets.simulate import SimulateWidget
from napari_symbac._widgets.tune import TuneWidget

if TYPE_CHECKING:
    import napari

__all__ = [
    "CalibrateDock",
    "DiagnoseDock",
    "ExportDock",
    "RealImageDock",
    "SimulateDock",
    "TuneDock",
    "WorkflowWidget",
]

#: Tab titles, in the order of the workflow.
TABS = ("1 Recording", "2 Simulate", "3 Tune + fit", "4 Diagnose", "5 Calibrate", "6 Export")


class WorkflowWidget(QTabWidget):
    """Recording -> Simulate -> Tune + fit -> Diagnose -> Calibrate -> Export, as tabs of one
    dock widget (Calibrate: from a field's recording straight to its matched dataset).

    The six step widgets are the ones napari also offers separately; they share the
    recording through its layer's metadata, so a tab can be used alone. The recording
    chosen in the first step becomes the later steps' recording (Simulate's, Tune's
    real image, Diagnose's, Calibrate's) once it has its pixel size: found as a user, choosing the
    ColiCoords sample's brightfield there left Simulate and Auto-fit on its fluorescence,
    the newest recording when they were made.
    """

    def __init__(self, viewer: napari.viewer.Viewer):
        super().__init__()
        self.setObjectName("symbac_workflow")
        self.real_image = RealImageWidget(viewer)
        self.simulate = SimulateWidget(viewer)
        self.tune = TuneWidget(viewer)
        self.diagnose = DiagnoseWidget(viewer)
        self.calibrate = CalibrateWidget(viewer)
        self.export = ExportWidget(viewer)
        tips = (
            "Open your recording, set its pixel size and microscope, paint and measure classes.",
            "Simulate growth with your recording's microscope and render it.",
            "Tune optics and noise live; Auto-fit the scene to your recording.",
            "Find, name and fit what the model misses in your recording; "
            "the updated settings go to Export.",
            "Fit a field's recording (agar pad, colonies) and make its matched dataset's "
            "settings in one step, as napari-symbac calibrate.",
            "Export a training dataset with the tuned, fitted or calibrated settings.",
        )
        for title, tip, widget in zip(TABS, tips, self._steps):
            area = _scroll_area(widget.native)
            widget.native.installEventFilter(self)
            index = self.addTab(area, title)
            self.setTabToolTip(index, tip)
        self._fit_widest_step()
        # the steps in tabs never shown are let go with the workflow's own dock
        release_with_dock(self, self._release_steps)
        self.real_image.image.changed.connect(self._share_recording)
        self.real_image.pixel_size.changed.connect(self._share_recording)

    def _release_steps(self) -> None:
        """Every step lets go of the viewer: the panel was closed (:mod:`._links`)."""
        for step in self._steps:
            step._links.release()

    @property
    def _steps(self) -> tuple:
        return (
            self.real_image, self.simulate, self.tune, self.diagnose, self.calibrate,
            self.export,
        )  # fmt: skip

    def _share_recording(self, _value=None) -> None:
        """The first step's recording chosen in the later steps (see the class notes)."""
        layer = self.real_image.image.value
        if layer is None or not is_recording(layer):
            return
        for choice in (
            self.simulate.recording,
            self.tune.reference,
            self.diagnose.reference,
            self.calibrate.recording,
        ):
            choice.reset_choices()
            if layer in choice.choices and choice.value is not layer:
                choice.value = layer

    def _fit_widest_step(self) -> None:
        """Never narrower than the widest step nor than the row of tabs: no sideways
        scrolling, no cut labels, every tab's title whole (found as a user: at 1366 x 768
        the last tab read "6 E" behind scroll arrows)."""
        widest = max(
            self.widget(i).widget().minimumSizeHint().width() for i in range(self.count())
        )
        scrollbar = self.style().pixelMetric(QStyle.PixelMetric.PM_ScrollBarExtent)
        width = max(widest + scrollbar + 16, self.tabBar().sizeHint().width() + 4)
        if self.minimumWidth() != width:
            self.setMinimumWidth(width)

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:
        """Follow a step that grows after a run (fit readouts, tables, reports)."""
        if event.type() == QEvent.Type.LayoutRequest:
            self._fit_widest_step()
        return super().eventFilter(watched, event)


class _StepArea(QScrollArea):
    """One step alone in a scroll area: up and down as the dock's height asks, never
    sideways (as wide as the step's widest row, followed when the step grows)."""

    def __init__(self, step: QWidget):
        super().__init__()
        _scroll_area(step, self)
        self.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        step.installEventFilter(self)
        self._fit_step()

    def _fit_step(self) -> None:
        scrollbar = self.style().pixelMetric(QStyle.PixelMetric.PM_ScrollBarExtent)
        width = self.widget().minimumSizeHint().width() + scrollbar + 4
        if self.minimumWidth() != width:
            self.setMinimumWidth(width)

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:
        if event.type() == QEvent.Type.LayoutRequest:
            self._fit_step()
        return super().eventFilter(watched, event)


class _Alone:
    """Mixin of a step docked alone: napari docks ``native``, here the step's scroll
    area; the step's rows stay in ``super().native``. The widget napari returns (and
    finds again, ``dock.inner_widget()``) is still the step, with its fields and buttons."""

    def __init__(self, viewer: napari.viewer.Viewer):
        super().__init__(viewer)
        area = _StepArea(super().native)
        area._magic_widget = self  # napari's inner_widget(): the step, not the area
        self._area = area

    @property
    def native(self) -> QWidget:
        # __dict__: magicgui reads ``native`` while the step is built, before the area
        return self.__dict__.get("_area") or super().native


class RealImageDock(_Alone, RealImageWidget):
    """*Real image and classes* docked alone (scrolls in its dock)."""


class SimulateDock(_Alone, SimulateWidget):
    """*Simulate and render* docked alone (scrolls in its dock)."""


class TuneDock(_Alone, TuneWidget):
    """*Tune optics and noise* docked alone (scrolls in its dock)."""


class DiagnoseDock(_Alone, DiagnoseWidget):
    """*Diagnose model mismatch* docked alone (scrolls in its dock)."""


class CalibrateDock(_Alone, CalibrateWidget):
    """*Calibrate to a recording* docked alone (scrolls in its dock)."""


class ExportDock(_Alone, ExportWidget):
    """*Export dataset* docked alone (scrolls in its dock)."""


def _scroll_area(step: QWidget, area: QScrollArea | None = None) -> QScrollArea:
    """``step`` in a frameless scroll area (``area``, or a new one) that gives it the
    area's width, its rows at the top."""
    area = QScrollArea() if area is None else area
    area.setWidgetResizable(True)
    area.setFrameShape(QFrame.Shape.NoFrame)
    _rows_at_the_top(step)
    area.setWidget(step)
    return area


def _rows_at_the_top(step: QWidget) -> None:
    """Keep the rows of ``step`` at its top, the room left below them.

    The scroll area stretches its widget to the tab's height; a step stretched so spread
    its spare height between its rows (found as a user: gaps of ~40 px between the
    *Recording* tab's rows at 1366 x 768). A stretch after the last row takes it
    (magicgui inserts rows by their index, before it), unless a row stretches to take it
    itself (:func:`~napari_symbac._widgets._forms.fill_height`: Diagnose's report).
    """
    layout = step.layout()
    if layout is None or not hasattr(layout, "addStretch"):
        return
    if not any(layout.stretch(i) for i in range(layout.count())):
        layout.addStretch(1)
