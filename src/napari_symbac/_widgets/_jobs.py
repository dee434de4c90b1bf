"""Background jobs of the dock widgets: one thread worker, its progress bar, its errors.

Why not ``thread_worker(progress=...)`` directly:

* napari's progress bar calls ``QApplication.processEvents()`` on every update, which
  delivers the next queued ``yielded`` signal inside the handler of the previous one.
  A worker that yields faster than the GUI draws (a loaded machine, a long simulation)
  then recurses until ``RecursionError``. Here events are queued and handled one at a
  time; of several yields waiting, only the newest is shown.
* superqt treats any ``RuntimeError`` raised in a generator worker (``ExportError``,
  ``RecursionError``) as "the worker was deleted": no ``errored``, no ``finished``, and
  the widget stays disabled. Here the generator never raises: its error is returned as
  a value and reported.
* Every error reaches the user as a napari notification (message and what to do), the
  widget gets its buttons back, and nothing is re-raised.
* When the widget is closed (the viewer closed mid-run) or its panel is (napari's close
  button on the dock: the step survives, unparented, while napari deletes the dock), the
  worker is asked to quit; a closed viewer's remaining events are dropped, a closed
  panel's job ends as its Cancel button ends it (no layers added, a preview removed).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import threading
from collections.abc import Callable, Generator
from typing import Any

__all__ = [
    "HEARTBEAT",
    "Job",
    "blocking_steps",
    "describe_error",
    "notify_error",
    "notify_info",
    "notify_warning",
    "removed_words",
]


@dataclasses.dataclass(frozen=True)
class _Failure:
    """An exception raised inside the worker, carried out as a plain value."""

    error: BaseException


def notify_error(message: str) -> None:
    """Show ``message`` as a napari error notification (never raises)."""
    from napari.utils.notifications import show_error

    show_error(message)


def notify_info(message: str) -> None:
    """Show ``message`` as a napari information notification (never raises)."""
    from napari.utils.notifications import show_info

    show_info(message)


def notify_warning(message: str) -> None:
    """Show ``message`` as a napari warning notification (never raises)."""
    from napari.utils.notifications import show_warning

    show_warning(message)


def describe_error(err: BaseException, what: str) -> str:
    """``what`` failed: the error's message, and the fix it names or a generic one."""
    text = str(err) or type(err).__name__
    if isinstance(err, ValueError):
        return f"{what} failed: {text}"
    return (
        f"{what} failed ({type(err).__name__}): {text}. Check the settings, then run it "
        "again; its traceback is printed in the terminal napari was started from."
    )


def removed_words(job: Job | None) -> str:
    """`` (its layer 'NAME' was removed)`` when ``job`` stopped for that
    (:meth:`Job.stop_if_removed`), else nothing: for a step's "cancelled" status."""
    if job is None or job.removed is None:
        return ""
    return f" (its layer '{job.removed}' was removed)"


def report_error(err: BaseException, what: str) -> None:
    """Notify ``what`` failed (:func:`describe_error`); an unexpected error (not a
    ``ValueError``, whose message names the fix) also logs its traceback, to stderr
    unless the application configured logging (found as a user: the message promised
    "the log has the details" and none was written anywhere)."""
    if not isinstance(err, ValueError):
        logging.getLogger("napari_symbac").error(
            "%s failed", what, exc_info=(type(err), err, err.__traceback__)
        )
    notify_error(describe_error(err, what))


class Job:
    """Run ``generator()`` in a napari thread worker, driving a progress bar.

    Parameters
    ----------
    generator
        A function returning a generator; each item it yields is ``(done, message)``
        (``done`` steps of ``total``) and its return value is the result.
    total
        Steps in all (``0``: an indeterminate bar).
    description
        Title of the progress bar in napari's activity dock.
    on_yield, on_return, on_error, on_abort, on_finish
        Callbacks in the GUI thread: the newest ``message``; the result; the exception
        (after it was shown as a notification unless ``on_error`` returns ``True``); a
        cancel; and always, last.
    owner
        The widget's Qt object; when it or one of the widgets holding it when the job
        starts (its dock) is destroyed, the worker is told to quit and no callback runs
        any more.

    Attributes
    ----------
    cancelled
        A :class:`threading.Event` set by :meth:`quit` and when ``owner`` is destroyed;
        work that runs outside the generator's yields (a blocking call) polls it.
    """

    def __init__(
        self,
        generator: Callable[[], Generator[tuple[int, Any], None, Any]],
        *,
        total: int,
        description: str,
        what: str,
        on_yield: Callable[[Any], None] | None = None,
        on_return: Callable[[Any], None] | None = None,
        on_error: Callable[[BaseException], bool | None] | None = None,
        on_abort: Callable[[], None] | None = None,
        on_finish: Callable[[], None] | None = None,
        owner: Any = None,
        cancelled: threading.Event | None = None,
    ) -> None:
        from napari.qt.threading import thread_worker
        from napari.utils import progress

        self._what = what
        self._callbacks = {
            "yield": on_yield,
            "return": on_return,
            "error": on_error,
            "abort": on_abort,
            "finish": on_finish,
        }
        self._queue: list[tuple[str, Any]] = []
        self._busy = False
        self._closed = False
        self._panel_gone = False  # a widget holding the owner was destroyed
        self._outcome = False  # a return, an error or an abort was delivered
        self.done = False
        self.cancelled = threading.Event() if cancelled is None else cancelled

        def guarded():
            try:
                result = yield from generator()
            except Exception as err:  # reported in the GUI thread, never re-raised
                return _Failure(err)
            return result

        self.progress = progress(total=total, desc=description)
        self.worker = thread_worker(guarded)()
        self.worker.yielded.connect(lambda item: self._post("yield", item))
        self.worker.returned.connect(lambda result: self._post("return", result))
        self.worker.errored.connect(lambda err: self._post("error", err))
        self.worker.aborted.connect(lambda: self._post("abort", None))
        # in the worker's thread: napari's own close (its task manager quits every worker
        # of the window) stops a blocking step too, not only the next yield (found as a
        # user: the viewer closed during Diagnose, which ran on for 101 s at full CPU and
        # ended in a segmentation fault at exit)
        from qtpy.QtCore import Qt

        self.worker.aborted.connect(self.cancelled.set, Qt.ConnectionType.DirectConnection)
        self.worker.finished.connect(lambda: self._post("finish", None))
        self._owner = owner
        self._holders: list[Any] = []  # the owner's ancestors while the job runs
        self._needed: list[Any] = []  # layers whose removal cancels the job
        self._layer_list: Any = None
        self.removed: str | None = None  # the name of the needed layer removed
        if owner is not None:
            owner.destroyed.connect(self._on_owner_destroyed)

    def start(self) -> None:
        """Start the worker thread."""
        self._watch_holders()
        self.worker.start()

    def _watch_holders(self) -> None:
        """Quit when a widget holding the owner is destroyed. Found as a user: napari's
        close button on a dock unparents the step and deletes the dock, the step itself
        lives on, and its job ran to the end and added its layers, for a removed
        recording too."""
        holder = self._owner.parentWidget() if self._owner is not None else None
        while holder is not None:
            holder.destroyed.connect(self._on_holder_destroyed)
            self._holders.append(holder)
            holder = holder.parentWidget()

    def _forget_holders(self) -> None:
        for holder in self._holders:  # (a deleted holder cannot be disconnected)
            with contextlib.suppress(RuntimeError, TypeError):
                holder.destroyed.disconnect(self._on_holder_destroyed)
        self._holders.clear()

    def _on_holder_destroyed(self, _obj=None) -> None:
        self._holders.clear()  # being deleted: nothing to disconnect
        self._panel_gone = True
        if self.done or self._closed or self.cancelled.is_set():
            return
        self.quit()  # as the Cancel button: the step tidies up (a preview removed)
        notify_info(f"{self._what} cancelled: its panel was closed")

    def stop_if_removed(self, layer_list: Any, layers: Any) -> None:
        """Quit, as the Cancel button does, when one of ``layers`` (those the job reads
        or shows its result over) is removed from ``layer_list`` while it runs; its name
        is then :attr:`removed`. Found as a user: a recording removed during Auto-fit
        ended, a minute later, in "AttributeError: 'NoneType' object has no attribute
        'data'"; Diagnose ran on for 112 s and added its layers without a word."""
        self._needed = [layer for layer in layers if layer is not None]
        self._layer_list = layer_list
        layer_list.events.removed.connect(self._on_layer_removed)

    def _on_layer_removed(self, event: Any) -> None:
        layer = getattr(event, "value", None)
        if not any(layer is needed for needed in self._needed):
            return
        if self.done or self._closed or self.cancelled.is_set():
            return
        self.removed = layer.name
        self.quit()
        notify_info(f"{self._what} cancelled: its layer '{layer.name}' was removed")

    def _forget_layers(self) -> None:
        if self._layer_list is not None:
            with contextlib.suppress(Exception):
                self._layer_list.events.removed.disconnect(self._on_layer_removed)
        self._layer_list = None
        self._needed = []

    def quit(self) -> None:
        """Ask the worker to stop at its next yield (and blocking work to cancel)."""
        self.cancelled.set()
        self.worker.quit()

    def _on_owner_destroyed(self, _obj=None) -> None:
        self._closed = True
        self._forget_layers()
        self._queue.clear()
        self.cancelled.set()
        self.worker.quit()
        self._close_progress()

    def _close_progress(self) -> None:
        if self.progress is not None:
            self.progress.close()
            self.progress = None

    # -- event queue ----------------------------------------------------------------------

    def _post(self, kind: str, payload: Any) -> None:
        if self._closed or (kind == "yield" and payload is HEARTBEAT):
            return
        if kind == "yield" and self._queue and self._queue[-1][0] == "yield":
            self._queue[-1] = (kind, payload)  # only the newest progress matters
        else:
            self._queue.append((kind, payload))
        if self._busy:  # we are inside a handler (processEvents): it drains the queue
            return
        self._busy = True
        try:
            while self._queue and not self._closed:
                kind, payload = self._queue.pop(0)
                try:
                    self._handle(kind, payload)
                except RuntimeError as err:
                    gone = self._panel_gone or self.cancelled.is_set()
                    if not (gone and _deleted_widget(err)):
                        report_error(err, f"{self._what} (showing its result)")
                    # else: the viewer closed around the step (its panel, or napari's
                    # close quitting the worker), its widgets deleted before the cancel
                    # arrived (found as a user: "Diagnose cancelled: its panel was
                    # closed", then an ERROR naming a deleted QLabel; and a Simulation's
                    # deleted QPushButton after the viewer closed mid-run)
                except Exception as err:  # a bug in a callback: report, keep the widget
                    report_error(err, f"{self._what} (showing its result)")
        finally:
            self._busy = False

    def _handle(self, kind: str, payload: Any) -> None:
        if kind == "return" and self.removed is not None and not isinstance(payload, _Failure):
            kind = "abort"  # a result that came back as its layer was removed: not shown
        callback = self._callbacks[kind]
        if kind in ("return", "error", "abort"):
            self._outcome = True
        if kind == "finish" and not self._outcome and self.cancelled.is_set():
            # superqt emits neither ``returned`` nor ``aborted`` when the generator ends
            # by itself after a quit was asked but before its next yield (a cancelled
            # blocking step returns at once): the cancel is what happened.
            self._outcome = True
            if self._callbacks["abort"] is not None:
                self._callbacks["abort"]()
        if kind == "yield":
            done, message = payload
            if self.progress is not None and done > self.progress.n:
                self.progress.update(done - self.progress.n)
            if callback is not None:
                callback(message)
        elif kind == "return" and isinstance(payload, _Failure):
            self._report(payload.error)
        elif kind == "error":
            self._report(payload)
        elif kind == "finish":
            self.done = True
            self._forget_holders()
            self._forget_layers()
            self._close_progress()
            if callback is not None:
                callback()
        elif callback is not None:
            callback(payload) if kind == "return" else callback()

    def _report(self, err: BaseException) -> None:
        callback = self._callbacks["error"]
        handled = callback(err) if callback is not None else None
        if not handled:
            report_error(err, self._what)


#: Yielded by :func:`blocking_steps` while its thread reports nothing: each yield is where
#: the worker sees a quit (napari's when the window closes), which the :class:`Job`
#: passes on to the blocking step; the Job shows nothing for it.
HEARTBEAT = object()
#: Seconds between heartbeats of a blocking step that reports nothing.
HEARTBEAT_S = 0.1


def blocking_steps(run, cancelled):
    """Run ``run(progress, cancel)`` in a thread; yield ``(done, (done, total))`` updates,
    and :data:`HEARTBEAT` every :data:`HEARTBEAT_S` without one.

    A generator for :class:`~napari_symbac._widgets._jobs.Job`; returns ``run``'s result
    and raises its exception.
    """
    import queue
    from concurrent.futures import ThreadPoolExecutor

    updates: queue.Queue = queue.Queue()
    with ThreadPoolExecutor(1) as pool:
        future = pool.submit(run, lambda done, total: updates.put((done, total)), cancelled)
        while not future.done() or not updates.empty():
            try:
                done, total = updates.get(timeout=HEARTBEAT_S)
            except queue.Empty:
                yield HEARTBEAT
                continue
            yield done, (done, total)
        return future.result()


def _deleted_widget(err: RuntimeError) -> bool:
    """Whether ``err`` is Qt's for a widget whose C++ object was deleted (PyQt's and
    PySide's wording)."""
    text = str(err)
    return "has been deleted" in text or "already deleted" in text
