"""Tracks as napari's Tracks layer takes them, from masks labelled by track id.

One row ``track id, frame, row, column`` per track and frame (the centroid of the
track's pixels there) and a graph ``{daughter: [mother]}``: what the GUI shows over a
simulation's ground truth (its labels keep each cell's id over its life) and over a
fitted time-lapse (:meth:`~napari_symbac.fit.lineage.Lineage.track_masks`).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy import ndimage

__all__ = ["napari_tracks"]


def napari_tracks(
    masks: np.ndarray, parents: Mapping[int, int]
) -> tuple[np.ndarray, dict[int, list[int]]]:
    """Track rows and division graph of ``(T, Y, X)`` track-id masks.

    Parameters
    ----------
    masks
        Per frame, each track's pixels labelled by its id (0: background).
    parents
        ``{daughter track: mother track}`` of every division (0: none).

    Returns
    -------
    data, graph
        ``(N, 4)`` float64 rows ``track id, frame, row, column`` (pixels), sorted by
        track and frame, a row wherever a track has pixels (a cell hidden in one frame
        has none there); and ``{daughter: [mother]}`` for the divisions whose tracks
        both have rows (napari refuses a graph that names a track without any).
    """
    masks = np.asarray(masks)
    if masks.ndim != 3:
        raise ValueError(f"masks must be (T, Y, X), not of shape {masks.shape}")
    rows = []
    for t, frame in enumerate(masks):
        tracks = np.unique(frame)
        tracks = tracks[tracks > 0]
        if tracks.size:
            centres = np.asarray(ndimage.center_of_mass(np.ones(frame.shape), frame, tracks))
            rows.append(np.column_stack([tracks, np.full(tracks.size, t), centres]))
    data = np.concatenate(rows).astype(np.float64) if rows else np.zeros((0, 4))
    data = data[np.lexsort((data[:, 1], data[:, 0]))]
    present = set(data[:, 0].astype(np.int64).tolist())
    graph = {
        int(daughter): [int(mother)]
        for daughter, mother in parents.items()
        if mother and int(daughter) in present and int(mother) in present
    }
    return data, graph
