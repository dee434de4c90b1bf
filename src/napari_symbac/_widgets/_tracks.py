"""A Tracks layer coloured as the Labels layer its tracks came from.

napari colours tracks by id through a continuous colormap and labels through a cyclic
table of contrasting colours, so a cell and its track had unrelated colours (found as a
user: nothing told which line belonged to which mask). Here each track takes its mask's
colour, through a feature ``mask_colour`` and a stepwise colormap napari keeps for it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["MASK_COLOUR_FEATURE", "replace_tracks"]

MASK_COLOUR_FEATURE = "mask_colour"


def replace_tracks(
    viewer: Any, name: str, data: np.ndarray, graph: dict, labels: Any, **kwargs: Any
) -> Any:
    """Replace the Tracks layer ``name`` by one of ``data`` coloured as ``labels``.

    Parameters
    ----------
    viewer
        The napari viewer.
    name
        The layer's name; a layer of that name is removed first, and none is added
        when ``data`` holds no row.
    data, graph
        Rows ``track id, frame, row, column`` and ``{daughter: [mother]}``
        (:func:`napari_symbac.track_points.napari_tracks`).
    labels
        The Labels layer whose ids are the track ids.
    **kwargs
        Passed to ``viewer.add_tracks`` (scale, translate, metadata, tail_length, ...).

    Returns
    -------
    napari.layers.Tracks or None
    """
    from napari.utils.colormaps import Colormap

    if name in viewer.layers:
        viewer.layers.remove(name)
    if not len(data):
        return None
    ids = np.unique(data[:, 0]).astype(np.int64)
    colours = np.asarray(labels.colormap.map(ids), dtype=float)
    colours[:, 3] = 1.0  # the mask's hue, drawn opaque as a line
    # id of rank r -> (r + 1/2) / n, inside the r-th of n equal steps of the colormap
    position = (np.searchsorted(ids, data[:, 0].astype(np.int64)) + 0.5) / ids.size
    colormap = Colormap(
        colours, controls=np.linspace(0.0, 1.0, ids.size + 1), interpolation="zero",
        name="track masks' colours",
    )  # fmt: skip
    return viewer.add_tracks(
        data, graph=graph, name=name, features={MASK_COLOUR_FEATURE: position},
        colormaps_dict={MASK_COLOUR_FEATURE: colormap}, color_by=MASK_COLOUR_FEATURE,
        **kwargs,
    )  # fmt: skip
