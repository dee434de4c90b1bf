"""The render-backend choice shared by the Simulate and Export tabs."""

from __future__ import annotations

from magicgui.widgets import ComboBox

from napari_symbac.optics import available_backends

__all__ = ["backend_choices", "backend_combo"]

_LABELS = {
    "scipy": "CPU (scipy, reference)",
    "torch": "torch, batched (GPU when present, else CPU)",
    "cupy": "GPU (cupy, convolution only)",
}


def backend_choices() -> list[tuple[str, str]]:
    """``(label, backend)`` for each render backend installed here (scipy always).

    Torch is offered when it is installed, without importing it (seconds); its device
    is chosen when rendering starts (cuda when torch sees a GPU).
    """
    return [(_LABELS[name], name) for name in available_backends()]


def backend_combo() -> ComboBox:
    """A "render on" combo box of :func:`backend_choices`, scipy selected."""
    return ComboBox(
        name="backend",
        label="render on",
        choices=backend_choices(),
        value="scipy",
        tooltip=(
            "Where frames are rendered: the CPU with scipy (the reference), or in batches "
            "on a torch device (a GPU when torch sees one; same images, another noise "
            "stream), or convolved on a GPU with cupy. Same as --backend on the command line."
        ),
    )
