"""Widget tests need a real X server (Xvfb): without one, vispy gets no OpenGL context
and adding the first layer fails deep inside ``glGetParameter``. Fail early and say so."""

from __future__ import annotations

import os

import pytest


@pytest.fixture(autouse=True, scope="session")
def _x_display(xvfb):
    """The X display the Qt canvas draws on (started by pytest-xvfb)."""
    if xvfb is None and not os.environ.get("DISPLAY"):
        pytest.fail(
            "no X display for the napari canvas: install Xvfb "
            "(apt-get install xvfb; pytest-xvfb then starts it) or run under xvfb-run"
        )
    return os.environ["DISPLAY"]


@pytest.fixture(autouse=True)
def _x_server_alive(xvfb):
    """Fail at once, saying why, when the session's Xvfb server has exited: every canvas
    would fail then (a layer added in a widget's callback only as a notification)."""
    server = getattr(xvfb, "_virtual_display", None)
    if server is not None and not server.is_alive():
        pytest.fail(f"the Xvfb server of this test session (display :{xvfb.display}) has exited")


@pytest.fixture(autouse=True)
def _no_worker_outlives_its_test():
    """A test that fails while a worker thread still runs must not leave it running into
    the next test (its signals would reach a closed viewer there)."""
    yield
    from superqt.utils._qthreading import WorkerBase

    WorkerBase.await_workers(msecs=120_000)


@pytest.fixture(autouse=True)
def _notifications_in_the_report():
    """Print every warning and error notification a test raised, so that a failed wait
    (a widget that never showed its result) says why in the test's captured output."""
    from napari.utils.notifications import NotificationSeverity, notification_manager

    def echo(notification):
        if notification.severity >= NotificationSeverity.WARNING:
            print(f"napari {notification.severity}: {notification.message}", flush=True)

    notification_manager.notification_ready.connect(echo)
    yield
    notification_manager.notification_ready.disconnect(echo)


@pytest.fixture
def notifications():
    """Messages of the napari notifications shown during the test."""
    from napari.utils.notifications import notification_manager

    seen: list[str] = []

    def record(notification):
        seen.append(str(notification.message))

    notification_manager.notification_ready.connect(record)
    yield seen
    notification_manager.notification_ready.disconnect(record)


@pytest.fixture
def tracks_in_mask_colours():
    """Assert that every track is drawn in its cell's label colour (found as a user:
    unrelated colours, nothing told which line belonged to which mask), and that the
    tracks are not all one colour."""
    import numpy as np

    def check(tracks, labels) -> None:
        ids = tracks.data[:, 0].astype(int)
        expected = np.asarray(labels.colormap.map(ids))[:, :3]
        np.testing.assert_allclose(np.asarray(tracks.track_colors)[:, :3], expected, atol=1e-6)
        assert len({tuple(np.round(c, 3)) for c in expected}) > 1

    return check
