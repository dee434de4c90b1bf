"""The widgets' background-job runner: no re-entrant handlers, errors as values."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("napari", reason="the [gui] extra (napari + Qt) is not installed")

from qtpy.QtWidgets import QApplication

from napari_symbac._widgets._jobs import Job


def test_fast_yields_never_recurse(qtbot):
    """A worker yielding faster than the GUI handles it, with a handler that processes
    events (as napari's progress bar does): handlers never nest (the RecursionError of
    the simulate widget), and the newest message is the last one shown."""
    depth = {"now": 0, "max": 0}
    shown: list[int] = []
    finished: list[bool] = []

    def on_yield(message):
        depth["now"] += 1
        depth["max"] = max(depth["max"], depth["now"])
        shown.append(message)
        QApplication.processEvents()
        depth["now"] -= 1

    def work():
        for index in range(1, 5001):
            yield index, index
        return "done"

    results = []
    job = Job(
        work,
        total=5000,
        description="test",
        what="Test",
        on_yield=on_yield,
        on_return=results.append,
        on_finish=lambda: finished.append(True),
    )
    job.start()
    qtbot.waitUntil(lambda: bool(finished), timeout=60_000)
    assert depth["max"] == 1
    assert shown[-1] == 5000
    assert shown == sorted(shown)
    assert results == ["done"]
    assert finished == [True]


def test_runtime_error_in_the_worker_is_reported_and_finishes(qtbot, caplog):
    """superqt swallows a RuntimeError from a generator worker (no errored, no
    finished); the runner reports it and always finishes. Its traceback is logged, where
    the message says (found as a user: "the log has the details", and no log had)."""
    from napari.utils.notifications import notification_manager

    errors, finished, seen = [], [], []
    notification_manager.notification_ready.connect(seen.append)

    def work():
        yield 1, None
        raise RuntimeError("disk full")

    job = Job(
        work,
        total=1,
        description="test",
        what="Export",
        on_error=errors.append,
        on_finish=lambda: finished.append(True),
    )
    job.start()
    qtbot.waitUntil(lambda: bool(finished), timeout=60_000)
    assert [str(e) for e in errors] == ["disk full"]
    assert any("Export failed (RuntimeError): disk full" in str(n.message) for n in seen)
    assert any("terminal napari was started from" in str(n.message) for n in seen)
    (record,) = [r for r in caplog.records if r.name == "napari_symbac"]
    assert record.levelname == "ERROR"
    assert record.getMessage() == "Export failed"
    assert "disk full" in caplog.text
    assert "in work\n    raise RuntimeError" in caplog.text


def test_a_quit_that_the_generator_outruns_still_reports_the_cancel(qtbot):
    """Found as a flaky Diagnose test (once in three suite runs): cancel asked while the
    generator was inside a blocking step, which then ended without another yield; superqt
    then emits only ``finished`` (no ``returned``, no ``aborted``) and the widget said
    "stopped" instead of "cancelled". The runner reports the cancel."""
    import threading

    inside, release = threading.Event(), threading.Event()
    calls: list[str] = []

    def work():
        yield 0, "started"
        inside.set()
        release.wait(30)  # a blocking step, cancelled meanwhile: it returns, no yield
        return "result of a cancelled step"

    job = _job_calling_back(work, "Test", calls)
    job.start()
    assert inside.wait(30)
    job.quit()
    release.set()
    qtbot.waitUntil(lambda: "finish" in calls, timeout=30_000)
    assert calls == ["abort", "finish"]


def test_a_job_whose_panel_is_closed_is_cancelled(qtbot):
    """Found as a user: napari's close button unparents the step and deletes its dock;
    the step lives on, and its job ran to the end and added its layers. The job is now
    cancelled as its Cancel button would (the abort callback runs, no result), and the
    user is told why."""
    import threading

    from napari.utils.notifications import notification_manager
    from qtpy.QtWidgets import QWidget

    dock = QWidget()
    step = QWidget(dock)
    calls: list[str] = []
    seen = []
    notification_manager.notification_ready.connect(seen.append)
    running = threading.Event()
    job = _job_calling_back(_endless_work(running), "Simulation", calls, owner=step)
    job.start()
    assert running.wait(30)
    step.setParent(None)  # what napari's remove_dock_widget does, then deletes the dock
    dock.deleteLater()
    qtbot.waitUntil(lambda: "finish" in calls, timeout=30_000)
    assert job.cancelled.is_set()
    assert calls == ["abort", "finish"]
    assert any("Simulation cancelled: its panel was closed" in str(n.message) for n in seen)


def test_a_job_whose_viewer_closed_around_it_reports_no_deleted_widget(qtbot):
    """Found as a user: closing the viewer while Diagnose ran said "Diagnose cancelled:
    its panel was closed", then "ERROR: Diagnose (showing its result) failed
    (RuntimeError): wrapped C/C++ object of type QLabel has been deleted": the cancel
    reached a status label the closing viewer had deleted. Only the cancel is said."""
    import threading

    from napari.utils.notifications import notification_manager
    from qtpy.QtWidgets import QLabel, QWidget

    dock = QWidget()
    step = QWidget(dock)
    status = QLabel(step)
    finished: list[bool] = []
    seen = []
    notification_manager.notification_ready.connect(seen.append)
    running = threading.Event()
    job = Job(_endless_work(running), total=0, description="test", what="Diagnose", owner=step,
              on_abort=lambda: status.setText("cancelled"),
              on_finish=lambda: finished.append(True))  # fmt: skip
    job.start()
    assert running.wait(30)
    step.setParent(None)
    status.deleteLater()  # the viewer's widgets go first
    dock.deleteLater()
    qtbot.waitUntil(lambda: bool(finished), timeout=30_000)
    assert not _is_alive(status)
    said = [str(n.message) for n in seen]
    assert any("Diagnose cancelled: its panel was closed" in m for m in said)
    assert not any("showing its result" in m for m in said), said


def test_a_finished_job_forgets_its_panel(qtbot):
    """A job that ended holds no connection to its dock: closing the dock later
    notifies nothing and keeps no finished job (and its result) alive."""
    from napari.utils.notifications import notification_manager
    from qtpy.QtWidgets import QWidget

    dock = QWidget()
    step = QWidget(dock)
    finished: list[bool] = []
    seen = []
    notification_manager.notification_ready.connect(seen.append)

    def work():
        yield 1, None
        return "done"

    job = Job(work, total=1, description="test", what="Simulation", owner=step,
              on_finish=lambda: finished.append(True))  # fmt: skip
    job.start()
    qtbot.waitUntil(lambda: bool(finished), timeout=30_000)
    assert job._holders == []
    step.setParent(None)
    dock.deleteLater()
    qtbot.waitUntil(lambda: not _is_alive(dock), timeout=10_000)
    assert not job.cancelled.is_set()
    assert not any("panel was closed" in str(n.message) for n in seen)


def _is_alive(widget) -> bool:
    try:
        widget.objectName()
    except RuntimeError:  # its C++ object was deleted
        return False
    return True


def _endless_work(running):
    """A job's work that yields until it is cancelled, setting ``running`` at each step."""
    import threading

    def work():
        for index in range(1, 100_000):
            running.set()
            yield index, index
            threading.Event().wait(0.01)
        return "finished without being cancelled"

    return work


def _job_calling_back(work, what: str, calls: list[str], **kwargs) -> Job:
    """A Job of ``work`` whose return, abort and finish are appended to ``calls``."""
    return Job(
        work,
        total=0,
        description="test",
        what=what,
        on_return=lambda result: calls.append("return"),
        on_abort=lambda: calls.append("abort"),
        on_finish=lambda: calls.append("finish"),
        **kwargs,
    )


def test_closing_the_viewer_stops_a_blocking_step_that_reports_nothing(make_napari_viewer, qtbot):
    """Found as a user: the viewer closed while Diagnose ran a held-out check; napari's
    close quit the worker (its task manager quits every worker of the window), but the
    blocking step only heard the Cancel button's event: it ran on for 101 s at full CPU
    and the process ended in a segmentation fault. The close now reaches the step."""
    import threading

    from napari_symbac._widgets._jobs import blocking_steps

    viewer = make_napari_viewer()
    viewer.add_image(np.zeros((8, 8)))  # a layer: napari's close path with its checks
    asked = threading.Event()
    started, stopped = threading.Event(), threading.Event()

    def run(progress, cancel):  # reports nothing until it is cancelled
        started.set()
        while not cancel():
            asked.wait(0.01)
        stopped.set()
        return "stopped"

    finished: list[bool] = []
    job = Job(lambda: (yield from blocking_steps(run, asked.is_set)), total=0,
              description="test", what="Diagnose", cancelled=asked,
              on_finish=lambda: finished.append(True))  # fmt: skip
    job.start()
    assert started.wait(30)
    viewer.close()
    assert stopped.wait(30), "the blocking step ran on after the viewer closed"
    assert job.cancelled.is_set()
