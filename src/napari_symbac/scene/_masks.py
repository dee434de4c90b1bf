"""A scene drawn from a real image's instance masks (the cell material of eq. OPL2).

Fitting the optics of a real recording needs a scene that overlays it pixel for
pixel. Instance masks (painted, or from a segmentation tool) give one: every mask
region is taken as a cell whose thickness across the region follows the chord of
a cylinder (the cross-section of a spherocylinder, eq. OPL2), so the optical path
through a cell falls to zero at its outline and two touching cells meet at a
zero-thickness seam, as the bright gaps of real colonies need.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from napari_symbac.scene._draw import Scene
from napari_symbac.settings import Microscope, RenderSettings

__all__ = ["cell_thickness_from_masks", "scene_from_masks"]


def cell_thickness_from_masks(labels: np.ndarray) -> np.ndarray:
    """Fraction of full depth filled by cell material, from instance labels.

    For each region, with ``e`` the distance (pixels) of a pixel centre from the
    region's edge (the Euclidean distance to the nearest outside pixel's centre
    minus one half) and ``r = max e`` its half width, the thickness is the chord of
    a cylinder of radius ``r``: ``sqrt(1 - (1 - e / r)^2)`` (1 on the centre line,
    ``sqrt(1 / r - 1 / (4 r^2))`` on the outermost pixels, 0 outside). Regions are
    treated one by one, so touching cells do not merge.

    Parameters
    ----------
    labels
        2-D integer instance mask (0 = background).

    Returns
    -------
    numpy.ndarray
        float32 image in ``[0, 1]`` of the shape of ``labels``.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2 or not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(
            f"labels must be a 2-D integer instance mask, got {labels.dtype} {labels.shape}"
        )
    if labels.min() < 0:
        raise ValueError("labels must be non-negative (0 = background, 1.. = cells)")
    out = np.zeros(labels.shape, np.float32)
    for index, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        grown = tuple(
            slice(max(b.start - 1, 0), min(b.stop + 1, n)) for b, n in zip(box, labels.shape)
        )
        region = labels[grown] == index
        # distance of each pixel centre from the region's edge (half a pixel less
        # than to the nearest outside pixel's centre), and the half width
        edge = ndimage.distance_transform_edt(np.pad(region, 1))[1:-1, 1:-1] - 0.5
        radius = max(float(edge.max()), 0.5)
        chord = np.sqrt(np.clip(1.0 - (1.0 - edge / radius) ** 2, 0.0, 1.0))
        out[grown] = np.where(region, chord, out[grown])
    return out


def scene_from_masks(
    labels: np.ndarray,
    microscope: Microscope,
    render: RenderSettings,
    *,
    depth_um: float = 1.0,
) -> Scene:
    """A :class:`~napari_symbac.scene.Scene` whose cells are the regions of ``labels``.

    Parameters
    ----------
    labels
        Instance mask of a real image at camera resolution (0 = background).
    microscope, render
        Pixel size, upsampling and PSF radius (the border) of the scene.
    depth_um
        Optical depth ``s_media`` (a cell's diameter is a good choice).

    Returns
    -------
    Scene
        Cells as :func:`cell_thickness_from_masks` at render resolution (each camera
        pixel repeated ``upsample`` times), media the rest, no device. The border
        around the field of view repeats the image mirror-wise, so a colony cut by
        the image edge goes on outside it rather than ending in a false halo.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2 or min(labels.shape) < 2:
        raise ValueError(f"labels must be a 2-D instance mask, got shape {labels.shape}")
    if not (np.isfinite(depth_um) and depth_um > 0):
        raise ValueError(f"depth_um must be positive, got {depth_um!r}")
    u, border = render.upsample, render.psf_radius_px
    fine_labels = np.repeat(np.repeat(labels.astype(np.int64), u, 0), u, 1)
    cells = cell_thickness_from_masks(fine_labels)
    cells = np.pad(cells, border, mode="symmetric")
    label_image = np.pad(fine_labels, border).astype(np.uint32)
    ids = np.unique(labels[labels > 0]).astype(np.int64)
    return Scene(
        cells=cells,
        media=1.0 - cells,
        device=np.zeros_like(cells),
        labels=label_image,
        border_px=border,
        upsample=u,
        camera_shape=labels.shape,
        pixel_size_um=microscope.pixel_size_um / u,
        depth_um=depth_um,
        cell_ids=ids,
    )
