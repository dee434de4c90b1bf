"""The viewer events a step listens to, let go when its panel is closed.

Found as a user: napari's close button on a dock unparents the step and deletes the
dock, and the step lives on, still connected to the viewer's layer events; opened
again, a second step joined it, and every recording opened without a pixel size was
warned of twice (three times after a second close).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any

from qtpy.QtCore import QEvent, QObject
from qtpy.QtWidgets import QDockWidget, QWidget


class ViewerLinks:
    """Connections of one step to the viewer (its layer list, its layers, its dims),
    undone at once by :meth:`release`, which the step's dock calls as it is destroyed
    (:func:`release_with_dock`)."""

    def __init__(self, native: QWidget) -> None:
        self._pairs: list[tuple[Any, Callable[..., Any]]] = []
        release_with_dock(native, self.release)

    def connect(self, emitter: Any, callback: Callable[..., Any]) -> None:
        """``emitter.connect(callback)``, remembered for :meth:`release`."""
        emitter.connect(callback)
        self._pairs.append((emitter, callback))

    def release(self) -> None:
        """Disconnect every connection made here (a layer already gone is skipped)."""
        for emitter, callback in self._pairs:
            with contextlib.suppress(Exception):
                emitter.disconnect(callback)
        self._pairs.clear()


class _DockWatch(QObject):
    """Waits for ``widget`` to be shown in a dock, then calls ``release`` when that
    dock is destroyed. A step in a tab not yet shown is released by the workflow's own
    watch (:class:`~napari_symbac._widgets.workflow.WorkflowWidget`)."""

    def __init__(self, widget: QWidget, release: Callable[[], None]) -> None:
        super().__init__(widget)
        self._widget = widget
        self._release = release
        self._dock: QDockWidget | None = None
        widget.installEventFilter(self)

    def eventFilter(self, watched: QObject, event: QEvent) -> bool:
        if event.type() == QEvent.Type.Show and self._dock is None:
            holder = self._widget.parentWidget()
            while holder is not None and not isinstance(holder, QDockWidget):
                holder = holder.parentWidget()
            if holder is not None:
                self._dock = holder
                holder.destroyed.connect(self._on_dock_destroyed)
        return False

    def _on_dock_destroyed(self, _obj: Any = None) -> None:
        self._dock = None
        self._release()


def release_with_dock(widget: QWidget, release: Callable[[], None]) -> None:
    """Call ``release`` once the :class:`QDockWidget` that ``widget`` is shown in is
    destroyed (napari's close button on the panel); nothing for a widget never docked."""
    _DockWatch(widget, release)
