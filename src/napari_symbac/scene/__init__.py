"""Scene drawing: cells, media and device at render resolution, masks, kymographs.

Implements supplement section 3: the 3-D spherocylinder cells (eq. OPL1-3), the
curvature transform (eq. 1), instance and semantic masks (eq. 4-5).
"""

from napari_symbac.scene._draw import (
    FrameCellsLike,
    Scene,
    draw_scene,
    spherocylinder_distance,
    vary_cell_brightness,
)
from napari_symbac.scene._kymograph import kymograph

__all__ = [
    "FrameCellsLike",
    "Scene",
    "draw_scene",
    "kymograph",
    "spherocylinder_distance",
    "vary_cell_brightness",
]
