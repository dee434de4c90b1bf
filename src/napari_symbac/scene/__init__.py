"""Scene drawing: cells, media and device at render resolution, masks, kymographs.

Implements supplement section 3: the 3-D spherocylinder cells (eq. OPL1-3), the
curvature transform (eq. 1), instance and semantic masks (eq. 4-5), the 2-D
fields of section 13 (agar pads, users' outlines; :func:`field_of`), a stain in
the cell envelope instead of the volume (fluorescence; :func:`envelope_stain`), and
the stain in slabs through the depth (eq. 16; :func:`depth_stain`).
"""

from napari_symbac.scene._debris import add_debris, debris_rng
from napari_symbac.scene._depth import depth_layer_centres_um, depth_stain, stain_layers
from napari_symbac.scene._draw import (
    FrameCellsLike,
    Scene,
    draw_scene,
    semantic_from_labels,
    spherocylinder_distance,
)
from napari_symbac.scene._field import (
    OUTLINE_WALL_THICKNESS_UM,
    Field,
    add_media_texture,
    field_of,
)
from napari_symbac.scene._gains import scale_cells
from napari_symbac.scene._kymograph import kymograph
from napari_symbac.scene._masks import cell_thickness_from_masks, scene_from_masks
from napari_symbac.scene._stain import (
    ENVELOPE_THICKNESS_UM,
    envelope_stain,
    envelope_weight,
    shell_chord_um,
    stained_fraction,
)

__all__ = [
    "ENVELOPE_THICKNESS_UM",
    "OUTLINE_WALL_THICKNESS_UM",
    "Field",
    "FrameCellsLike",
    "Scene",
    "add_debris",
    "add_media_texture",
    "cell_thickness_from_masks",
    "debris_rng",
    "depth_layer_centres_um",
    "depth_stain",
    "draw_scene",
    "envelope_stain",
    "envelope_weight",
    "field_of",
    "kymograph",
    "scale_cells",
    "scene_from_masks",
    "semantic_from_labels",
    "shell_chord_um",
    "spherocylinder_distance",
    "stain_layers",
    "stained_fraction",
]
