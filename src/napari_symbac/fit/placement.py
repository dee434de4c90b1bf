"""Where the trench lies in a real image, and drawing fitted cells in image coordinates."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from napari_symbac.scene import Field, Scene, draw_scene
from napari_symbac.settings import Microscope, RenderSettings, TrenchGeometry
from napari_symbac.sim import FrameCells

__all__ = ["TrenchPlacement", "draw_fitted"]


@dataclass(frozen=True)
class TrenchPlacement:
    """Where the trench lies in the image (um from the image's top-left corner).

    Attributes
    ----------
    left_um
        Position of the left wall.
    width_um
        Trench width.
    top_um
        Position of the closed end (negative: above the image).
    depth_um
        Optical depth of the trench (``s_media``; not fitted).
    closed_end
        ``"square"`` or ``"round"`` (a semicircle of diameter ``width_um``), as
        :attr:`TrenchGeometry.closed_end`; not fitted.
    """

    left_um: float
    width_um: float
    top_um: float
    depth_um: float = 1.2
    closed_end: Literal["square", "round"] = "square"

    def __post_init__(self) -> None:
        for name in ("left_um", "width_um", "top_um", "depth_um"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f"TrenchPlacement.{name} must be finite")
            object.__setattr__(self, name, value)
        if self.width_um <= 0 or self.depth_um <= 0:
            raise ValueError("TrenchPlacement.width_um and depth_um must be positive")
        if self.closed_end not in ("square", "round"):
            raise ValueError(
                f"TrenchPlacement.closed_end must be 'square' or 'round', got {self.closed_end!r}"
            )


def draw_fitted(
    cells: FrameCells,
    trench: TrenchPlacement | None,
    camera_shape: tuple[int, int],
    microscope: Microscope,
    render: RenderSettings,
    depth_um: float = 1.2,
    curvature: dict[int, tuple[float, float, float]] | None = None,
) -> Scene:
    """Draw fitted cells (image coordinates) with :func:`draw_scene`.

    The trench is placed by ``trench_origin_um`` in a field of view of the image's
    shape; ``trench=None`` is an open field (agar pad: media everywhere, no device).
    """
    rows, cols = camera_shape
    if trench is None:
        px = microscope.pixel_size_um
        field = Field(cols * px, rows * px, depth_um=depth_um)
        return draw_scene(cells, TrenchGeometry(), microscope, render, curvature, field=field)
    relative = FrameCells(
        ids=cells.ids,
        x_um=cells.x_um - trench.left_um,
        y_um=cells.y_um - trench.top_um,
        angle_rad=cells.angle_rad,
        length_um=cells.length_um,
        width_um=cells.width_um,
    )
    # Length and margin do not matter: camera_shape sets the field of view.
    geometry = TrenchGeometry(
        width_um=trench.width_um,
        depth_um=trench.depth_um,
        margin_um=0.0,
        closed_end=trench.closed_end,
    )
    return draw_scene(
        relative,
        geometry,
        microscope,
        render,
        curvature,
        trench_origin_um=(trench.left_um, trench.top_um),
        camera_shape=(rows, cols),
    )
