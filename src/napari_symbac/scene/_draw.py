"""Scene drawing: cells, media and device as fractions of the optical depth (section 3).

A *scene* is the sample before the optics: three material images (cells, media,
device), each holding the fraction of the trench depth that the material fills
along the optical axis at every render-resolution pixel, plus the instance labels.
Eq. 3 weights them with the effective intensities; eq. OPL1-3 turns them into a
physical optical path length.
"""

from __future__ import annotations

import functools
import hashlib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any, Protocol

import numpy as np
from numba import njit

from napari_symbac.arguments import require_argument
from napari_symbac.scene._field import Field, field_images
from napari_symbac.scene._raster import media_fraction, rasterise_cells
from napari_symbac.settings import Microscope, RenderSettings, TrenchGeometry

__all__ = [
    "FrameCellsLike",
    "Scene",
    "draw_scene",
    "semantic_from_labels",
    "spherocylinder_distance",
]

_MAX_ID = np.iinfo(np.uint32).max
#: The most render pixels (upsampled, PSF border included) a scene is drawn in.
MAX_RENDER_PIXELS = 64_000_000


class FrameCellsLike(Protocol):
    """What :func:`draw_scene` needs from a frame of the simulation (duck-typed)."""

    ids: np.ndarray
    x_um: np.ndarray
    y_um: np.ndarray
    angle_rad: np.ndarray
    length_um: np.ndarray
    width_um: np.ndarray


def _fingerprint(array: np.ndarray) -> str:
    # SHA-256 runs at about 2 GB/s where the CPU has SHA instructions (twice blake2b).
    digest = hashlib.sha256()
    digest.update(str((array.shape, array.dtype.str)).encode())
    digest.update(memoryview(np.ascontiguousarray(array)).cast("B"))
    return digest.hexdigest()[:32]


def _readonly(array: np.ndarray) -> np.ndarray:
    array = np.ascontiguousarray(array)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class Scene:
    """The sample of one frame at render resolution, before any optics.

    Attributes
    ----------
    cells, media, device
        float32 images at render resolution (pixel = camera pixel / ``upsample``),
        including a border of ``border_px`` pixels on every side. Each value is the
        fraction of the optical depth ``depth_um`` filled by that material, so that
        eq. 3 reads ``I = I_c cells + I_m media + I_t device``; a device pixel is
        ``device = 1``, an empty trench pixel ``media = 1`` and the centre-line of a
        cell as thick as the trench is deep ``cells = 1``. ``cells + media + device
        = 1`` everywhere. :func:`draw_scene` computes ``media`` on first access
        (``open - cells``, the same values): bulk drawing that never reads it does not
        pay for a third frame-sized image.
    labels
        uint32 instance mask at render resolution, value = cell id (0 = no cell).
        :func:`draw_scene` keeps it as uint16 when every id fits and makes the
        uint32 image on first access (the masks are made from the uint16 one).
    border_px
        Width of the border (render pixels) outside the camera's field of view.
    upsample
        Render pixels per camera pixel.
    camera_shape
        ``(rows, columns)`` of the camera image.
    pixel_size_um
        Render-resolution pixel size.
    depth_um
        Optical depth of the trench layer (``s_media`` of eq. OPL2-3).
    cell_ids
        Ids of the cells drawn (including any that fall outside the field of view).
    """

    cells: np.ndarray
    media: np.ndarray
    device: np.ndarray
    labels: np.ndarray
    border_px: int
    upsample: int
    camera_shape: tuple[int, int]
    pixel_size_um: float
    depth_um: float
    cell_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def __post_init__(self) -> None:
        shape = None
        for name in ("cells", "media", "device"):
            arr = _checked_image(name, getattr(self, name))
            if shape is not None and arr.shape != shape:
                raise ValueError(f"Scene.{name} has shape {arr.shape}, expected {shape}")
            shape = arr.shape
            object.__setattr__(self, name, arr)
        labels = np.asarray(self.labels)
        if labels.shape != shape:
            raise ValueError(f"Scene.labels has shape {labels.shape}, expected {shape}")
        object.__setattr__(self, "labels", _readonly(labels.astype(np.uint32, copy=False)))
        object.__setattr__(
            self, "camera_shape", (int(self.camera_shape[0]), int(self.camera_shape[1]))
        )
        expected = (
            self.camera_shape[0] * self.upsample + 2 * self.border_px,
            self.camera_shape[1] * self.upsample + 2 * self.border_px,
        )
        if shape != expected:
            raise ValueError(
                f"Scene images have shape {shape} but camera_shape {self.camera_shape}, "
                f"upsample {self.upsample} and border_px {self.border_px} imply {expected}"
            )
        object.__setattr__(self, "cell_ids", _readonly(np.asarray(self.cell_ids, np.int64)))

    @classmethod
    def _unchecked(
        cls, pending: Mapping[str, Callable[[], np.ndarray]] | None = None, **values: Any
    ) -> Scene:
        """A scene from values that already satisfy ``__post_init__`` (no checks, no copies).

        For :func:`draw_scene` and the ``replace_*`` methods, whose images are
        read-only, C-contiguous, finite float32 (labels uint32, ids int64) of matching
        shapes by construction; skipping the checks saves several passes over the
        images per frame. An image named in ``pending`` (instead of ``values``) is
        made by calling its function on first access, then kept read-only.
        """
        scene = object.__new__(cls)
        for name in _FIELDS:
            if pending is None or name not in pending:
                object.__setattr__(scene, name, values[name])
        if pending:
            object.__setattr__(scene, "_pending", dict(pending))
        return scene

    def __getattr__(self, name: str) -> Any:
        # Called only when the attribute is not set: an image still pending.
        make = self.__dict__.get("_pending", {}).get(name)
        if make is None:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        image = make()
        image.setflags(write=False)
        object.__setattr__(self, name, image)
        return image

    def _replace(self, name: str, image: np.ndarray) -> Scene:
        image = _checked_image(name, image)
        if image.shape != self.shape:
            raise ValueError(f"Scene.{name} has shape {image.shape}, expected {self.shape}")
        # Images still pending stay pending: their functions hold their own inputs.
        pending = {
            f: make
            for f, make in self.__dict__.get("_pending", {}).items()
            if f != name and f not in self.__dict__
        }
        values = {f: self.__dict__[f] for f in _FIELDS if f in self.__dict__}
        values[name] = image
        scene = Scene._unchecked(pending, **values)
        # The labels are the same array: so are the camera-resolution masks, and the
        # content hashes of the images that did not change.
        for kept in ("_masks", "_narrow_labels", "_depth_profile"):
            if kept in self.__dict__:
                object.__setattr__(scene, kept, self.__dict__[kept])
        known = {
            **self.__dict__.get("_known_fingerprints", {}),
            **self.__dict__.get("_fingerprints", {}),
        }
        known.pop(name, None)
        if known:
            object.__setattr__(scene, "_known_fingerprints", known)
        return scene

    @property
    def fingerprints(self) -> dict[str, str]:
        """Content hashes of ``cells``, ``media`` and ``device`` (cache keys).

        Computed on first use (the images are read-only, so they cannot go stale):
        bulk rendering, which does not cache, never pays for them.
        """
        cached = self.__dict__.get("_fingerprints")
        if cached is None:
            known = self.__dict__.get("_known_fingerprints", {})
            cached = {
                name: known.get(name) or _fingerprint(getattr(self, name))
                for name in ("cells", "media", "device")
            }
            object.__setattr__(self, "_fingerprints", cached)
        return cached

    @property
    def shape(self) -> tuple[int, int]:
        """Shape of the render-resolution images (border included)."""
        return self.cells.shape  # type: ignore[return-value]

    def interior(self, image: np.ndarray) -> np.ndarray:
        """Crop a render-resolution image to the camera's field of view."""
        b = self.border_px
        return image[b : image.shape[0] - b, b : image.shape[1] - b]

    def _camera_masks(self) -> tuple[np.ndarray, np.ndarray]:
        # Computed once per scene (the labels are read-only, so they cannot go stale).
        cached = self.__dict__.get("_masks")
        if cached is None:
            # The uint16 labels of draw_scene where it kept them: the same values.
            labels = self.__dict__.get("_narrow_labels")
            if labels is None:
                labels = self.labels
            cached = _camera_masks(labels, self.border_px, self.upsample, self.camera_shape)
            for mask in cached:
                mask.setflags(write=False)
            object.__setattr__(self, "_masks", cached)
        return cached

    def camera_labels(self) -> np.ndarray:
        """Instance mask at camera resolution (eq. 4-5 per cell), ``uint32``.

        Each camera pixel takes the label covering most of its ``upsample x upsample``
        render pixels (background counts as a label; of equal counts, the first in
        row-major order within the block), so touching cells keep touching and ids are
        preserved exactly (no wrap-around, whatever the count). Computed once per
        scene, together with :meth:`semantic_mask`; each call returns a new array.
        """
        return self._camera_masks()[0].copy()

    def semantic_mask(self) -> np.ndarray:
        """Semantic mask at camera resolution, ``uint8`` (eq. 4-5).

        Pixels of cells are 1 and background 0; wherever two different cells touch
        (8-connectivity), the pixel of the cell with the larger id is set to 0, so
        cells are always separated by zero pixels (the DeLTA convention). Computed
        from :meth:`camera_labels` once per scene; each call returns a new array.
        """
        return self._camera_masks()[1].copy()

    def optical_path_length(
        self,
        n_cell: float = 1.39,
        n_media: float = 1.333,
        n_pdms: float = 1.41,
        pdms_thickness_um: float | None = None,
    ) -> np.ndarray:
        """Physical optical path length image in um (eq. OPL1-3).

        ``OPL = n_PDMS (s_PDMS - s_media) + s_media (n_cell c + n_media m + n_PDMS t)``
        with ``c, m, t`` the material fractions of this scene: a device pixel gives
        OPL1, a pixel through a cell OPL2, an empty trench pixel OPL3.

        Parameters
        ----------
        n_cell, n_media, n_pdms
            Refractive indices (free parameters of the supplement).
        pdms_thickness_um
            Total PDMS thickness ``s_PDMS``; defaults to the trench depth.
        """
        for name, value in (("n_cell", n_cell), ("n_media", n_media), ("n_pdms", n_pdms)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive refractive index, got {value!r}")
        s_pdms = self.depth_um if pdms_thickness_um is None else float(pdms_thickness_um)
        if not (math.isfinite(s_pdms) and s_pdms >= self.depth_um):
            raise ValueError(
                f"pdms_thickness_um={pdms_thickness_um!r} must be at least the trench depth "
                f"({self.depth_um} um)"
            )
        opl = self.depth_um * (n_cell * self.cells + n_media * self.media + n_pdms * self.device)
        return (opl + n_pdms * (s_pdms - self.depth_um)).astype(np.float32)

    @property
    def depth_profile(self) -> np.ndarray | None:
        """Share of each pixel's cells image in each slab through the depth, ``(N, *shape)``
        (eq. 16; :func:`~napari_symbac.scene.depth_stain`), or ``None`` (not drawn).

        A geometric share (it adds up to 1 at every pixel), so the copies of
        :meth:`replace_cells` with per-pixel gains and :meth:`replace_media` keep it.
        """
        return self.__dict__.get("_depth_profile")

    def with_depth_profile(self, profile: np.ndarray) -> Scene:
        """A copy of this scene with ``profile`` as its :attr:`depth_profile`."""
        profile = np.ascontiguousarray(profile, np.float32)
        if profile.ndim != 3 or profile.shape[1:] != self.shape or not profile.shape[0]:
            raise ValueError(
                f"a depth profile has shape (layers, *{self.shape}), got {profile.shape}"
            )
        if not np.all(np.isfinite(profile)):
            raise ValueError("the depth profile must be finite")
        scene = object.__new__(Scene)
        scene.__dict__.update(self.__dict__)
        object.__setattr__(scene, "_depth_profile", _readonly(profile))
        return scene

    def replace_cells(self, cells: np.ndarray) -> Scene:
        """A copy of this scene with a new cells image (e.g. per-cell brightness)."""
        return self._replace("cells", cells)

    def replace_media(self, media: np.ndarray) -> Scene:
        """A copy of this scene with a new media image (e.g. background texture)."""
        return self._replace("media", media)


_FIELDS = tuple(f.name for f in fields(Scene))


#: Pixels of a band of rows that the semantic mask's minimum filter runs on at a time
#: (contiguous, cache-sized).
_MASK_CHUNK_PIXELS = 1 << 18


@njit(cache=True, nogil=True)
def _block_labels(
    labels: np.ndarray, border: int, u: int, rows: int, cols: int
) -> np.ndarray:
    """Majority label (uint32) of every ``u x u`` block of the ``rows x cols`` blocks of
    ``labels`` inside its ``border``, ``u >= 2``.

    Of equal counts the first in row-major order within the block wins. A row of
    blocks at a time: each pixel is flagged where a row below it in its block differs
    from it or it differs from its left neighbour (contiguous passes over whole image
    rows, vector instructions); a block without a flag is uniform and takes its first
    pixel, one with a flag (a cell edge, or a block boundary that a label edge
    happens to follow) is voted on: for each pixel in row-major order, how many of
    the block share its label; the first of the largest count wins.
    """
    out = np.empty((rows, cols), np.uint32)
    width = cols * u
    flagged = np.zeros(-(-width // 8) * 8, np.uint8)
    words = flagged.view(np.uint64)  # eight flags at a time
    block = np.empty(u * u, labels.dtype)
    for bi in range(rows):
        r0 = border + bi * u
        top = labels[r0, border : border + width]
        flagged[0] = 0
        for j in range(1, width):
            flagged[j] = top[j] != top[j - 1]
        for dy in range(1, u):
            below = labels[r0 + dy, border : border + width]
            for j in range(width):
                flagged[j] |= below[j] != top[j]
        for bj in range(cols):
            out[bi, bj] = top[bj * u]
        voted = -1
        for w in range(words.size):
            if words[w] == 0:
                continue
            for j in range(8 * w, 8 * w + 8):
                bj = j // u
                if not flagged[j] or bj == voted:
                    continue
                voted = bj
                for dy in range(u):
                    for dx in range(u):
                        block[dy * u + dx] = labels[r0 + dy, border + bj * u + dx]
                best = 0
                for k in range(u * u):
                    count = 0
                    for m in range(u * u):
                        count += block[m] == block[k]
                    if count > best:
                        best = count
                        out[bi, bj] = block[k]
    return out


def semantic_from_labels(labels: np.ndarray) -> np.ndarray:
    """Semantic mask (uint8) of an instance mask: cells, minus pixels next to smaller ids.

    A cell pixel is 0 where a neighbour (8-connectivity) is a cell of a smaller id.
    With ``labels - 1`` (background wraps round to the largest value) that is where
    the 3 x 3 minimum is below the pixel's own value. The minimum runs on the
    flattened, padded rows of a band at a time (contiguous, cache-sized): along a
    row over offsets -1, 0, 1, then across rows over offsets -width, 0, width.
    """
    rows, cols = labels.shape
    width = cols + 2
    keep = np.empty((rows, cols), np.uint8)
    chunk = max(1, _MASK_CHUNK_PIXELS // width)
    one = np.uint32(1)
    for r0 in range(0, rows, chunk):
        r1 = min(r0 + chunk, rows)
        lo, hi = max(r0 - 1, 0), min(r1 + 1, rows)
        # rows r0 - 1 .. r1 of the image, padded with the largest value
        shifted = np.full((r1 - r0 + 2, width), np.iinfo(np.uint32).max, np.uint32)
        np.subtract(labels[lo:hi], one, out=shifted[lo - r0 + 1 : hi - r0 + 1, 1:-1])
        flat = shifted.ravel()
        across = np.minimum(flat[:-2], flat[1:-1])
        np.minimum(across, flat[2:], out=across)
        lowest = np.empty((r1 - r0) * width, np.uint32)
        np.minimum(across[: -2 * width], across[width:-width], out=lowest[:-2])
        np.minimum(lowest[:-2], across[2 * width :], out=lowest[:-2])
        # lowest[i * width + j] is the minimum around band row i, column j.
        own = np.equal(lowest.reshape(r1 - r0, width)[:, :cols], shifted[1:-1, 1:-1])
        own &= labels[r0:r1] > 0
        keep[r0:r1] = own
    return keep


def _camera_masks(
    labels_full: np.ndarray, border: int, u: int, camera_shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """Instance and semantic masks at camera resolution of the interior labels.

    The majority vote runs only on the ``u x u`` blocks that are not uniform (cell
    edges); the semantic mask is one 3 x 3 minimum filter of the instance mask.
    """
    rows, cols = camera_shape
    b = border
    if u > 1:
        labels = _block_labels(np.ascontiguousarray(labels_full), b, u, rows, cols)
    else:
        labels = np.array(labels_full[b : b + rows, b : b + cols], np.uint32)
    return labels, semantic_from_labels(labels)


def _checked_image(name: str, image: Any) -> np.ndarray:
    """``image`` as a read-only, C-contiguous float32 2-D array of finite values."""
    arr = np.asarray(image, dtype=np.float32)
    if arr.ndim != 2:
        raise ValueError(f"Scene.{name} must be a 2-D image, got shape {arr.shape}")
    # A NaN or an infinity makes the sum non-finite; a finite sum means all are finite
    # (the exact test runs only when the sum is not, e.g. on float32 overflow).
    if not math.isfinite(np.add.reduce(arr, axis=None)) and not np.all(np.isfinite(arr)):
        raise ValueError(f"Scene.{name} contains NaN or infinite values")
    return _readonly(arr)


def _column(cells: Any, name: str, n: int | None) -> np.ndarray:
    try:
        value = np.asarray(getattr(cells, name), dtype=np.float64)
    except AttributeError as err:
        raise ValueError(f"cells must have an attribute {name!r} (see FrameCells)") from err
    if value.ndim != 1:
        raise ValueError(f"cells.{name} must be a 1-D array, got shape {value.shape}")
    if n is not None and value.shape[0] != n:
        raise ValueError(f"cells.{name} has {value.shape[0]} entries, cells.ids has {n}")
    if not np.all(np.isfinite(value)):
        raise ValueError(f"cells.{name} contains NaN or infinite values")
    return value


def spherocylinder_distance(
    x_um: np.ndarray,
    y_um: np.ndarray,
    centre_um: tuple[float, float],
    angle_rad: float,
    length_um: float,
    width_um: float,
    curvature: tuple[float, float, float] | None = None,
) -> np.ndarray:
    """Distance from points to the axis segment of a (curved) spherocylinder.

    The cell's axis points along ``(sin angle, cos angle)`` in ``(x, y)``, with ``y``
    increasing down the image, so ``angle = 0`` is vertical. The axis segment has
    length ``length - width`` (pole to pole minus the two caps).

    Curvature is the row roll of eq. 1, applied as a shift perpendicular to the axis
    by ``a sin(pi l / b + c)``, where ``l`` in [0, 1] is the position along the cell
    from its top pole *as a fraction of the cell length* (so ``b`` is dimensionless:
    ``b = 1`` bends the cell into one half sine, a crescent) and ``a`` is in um. For
    a vertical cell this is exactly a roll of the image rows, done with sub-pixel
    precision; the image and the mask are both derived from this distance, so they
    bend alike.
    """
    r = width_um / 2
    half = max(length_um / 2 - r, 0.0)
    dx = x_um - centre_um[0]
    dy = y_um - centre_um[1]
    sin_a, cos_a = math.sin(angle_rad), math.cos(angle_rad)
    s = dx * sin_a + dy * cos_a
    t = dx * cos_a - dy * sin_a
    if curvature is not None:
        a_um, b, c = curvature
        ell = np.clip((s + length_um / 2) / length_um, 0.0, 1.0)
        t = t - a_um * np.sin(ell * math.pi / b + c)
    s_on = np.clip(s, -half, half)
    return np.sqrt((s - s_on) ** 2 + t**2)


def _check_curvature(curvature: Mapping[int, tuple[float, float, float]] | None) -> dict:
    if curvature is None:
        return {}
    out = {}
    for key, value in curvature.items():
        try:
            a_um, b, c = (float(v) for v in value)
        except (TypeError, ValueError) as err:
            raise ValueError(
                f"curvature[{key!r}] must be a tuple (a_um, b, c) of eq. 1, got {value!r}"
            ) from err
        if not all(math.isfinite(v) for v in (a_um, b, c)):
            raise ValueError(f"curvature[{key!r}] = {value!r}: a, b, c must be finite")
        if a_um == 0:
            continue  # straight, whatever b and c (the simulator's "no curvature" is zeros)
        if b == 0:
            raise ValueError(f"curvature[{key!r}] = {value!r}: b must be non-zero")
        out[int(key)] = (a_um, b, c)
    return out


def _coverage(centres_um: np.ndarray, pixel_um: float, low_um: float, high_um: float) -> np.ndarray:
    """Fraction of each pixel (centred at ``centres_um``) inside ``[low, high]``."""
    lo = np.maximum(centres_um - pixel_um / 2, low_um)
    hi = np.minimum(centres_um + pixel_um / 2, high_um)
    return np.clip((hi - lo) / pixel_um, 0.0, 1.0)


#: Sub-rows per render pixel over which a round closed end's coverage is averaged.
_END_SUBROWS = 16


@functools.lru_cache(maxsize=16)
def _trench_images(
    shape: tuple[int, int],
    border: int,
    px: float,
    left_um: float,
    top_um: float,
    width_um: float,
    closed_end: str = "square",
) -> tuple[np.ndarray, np.ndarray, str]:
    """Trench (media-filled) and device fractions of every render pixel (read-only).

    ``left_um`` and ``top_um`` place the trench's left wall and closed end in the
    field of view. They depend on the geometry only, so every frame of a trench shares
    them (and the device image's fingerprint). A ``"round"`` closed end is a
    semicircle of diameter ``width_um`` (PDMS in the corners); its pixels' coverage
    is exact across each of :data:`_END_SUBROWS` sub-rows and averaged over them.
    """
    yc = (np.arange(shape[0]) - border + 0.5) * px
    xc = (np.arange(shape[1]) - border + 0.5) * px
    trench_frac = np.outer(
        _coverage(yc, px, top_um, np.inf), _coverage(xc, px, left_um, left_um + width_um)
    ).astype(np.float32)
    if closed_end == "round":
        r = width_um / 2
        cx, cy = left_um + r, top_um + r
        # Rows that reach into the cap ``top <= y < top + r``; below it the square
        # coverage above is exact.
        cap = np.flatnonzero((yc + px / 2 > top_um) & (yc - px / 2 < cy))
        if cap.size:
            sub = (np.arange(_END_SUBROWS) + 0.5) / _END_SUBROWS - 0.5
            ys = yc[cap, None] + sub[None, :] * px  # (rows, sub-rows)
            half = np.where(ys >= cy, r, np.sqrt(np.clip(r * r - (cy - ys) ** 2, 0.0, None)))
            half = np.where(ys < top_um, -1.0, half)  # above the end: no trench
            lo = np.maximum(xc[None, None, :] - px / 2, cx - half[..., None])
            hi = np.minimum(xc[None, None, :] + px / 2, cx + half[..., None])
            frac = np.clip((hi - lo) / px, 0.0, 1.0).mean(axis=1)
            trench_frac[cap] = frac.astype(np.float32)
    device = 1.0 - trench_frac
    trench_frac.setflags(write=False)
    device.setflags(write=False)
    return trench_frac, device, _fingerprint(device)


@functools.lru_cache(maxsize=16)
def _device_fingerprint(field: Field, shape: tuple[int, int], border: int, px: float) -> str:
    return _fingerprint(field_images(field, shape, border, px)[1])


def draw_scene(
    cells: FrameCellsLike,
    trench: TrenchGeometry,
    microscope: Microscope,
    render: RenderSettings,
    curvature: Mapping[int, tuple[float, float, float]] | None = None,
    *,
    field: Field | None = None,
    trench_origin_um: tuple[float, float] | None = None,
    camera_shape: tuple[int, int] | None = None,
) -> Scene:
    """Draw one frame of a trench, chamber, agar pad or outline as cells, media and device.

    Cells are 3-D spherocylinders lying at mid-depth: the light crosses a chord of
    thickness ``2 sqrt(r^2 - d^2)`` (``d`` = distance to the axis segment), which is
    the ``2 r sin(theta)`` of eq. OPL2. The field of view is the trench plus
    ``trench.margin_um`` of PDMS on the left and right and ``trench.shown_top_um`` at
    the closed end (top); the
    open end is flush with the bottom edge (the trench runs on into the border). The
    closed end is square or, with ``trench.closed_end="round"``, a semicircle.
    Around the field of view a border of ``render.psf_radius_px`` render pixels is
    drawn, so the convolution of eq. 15 has no edge effects. A chamber (section
    13.1) is a wide trench and is drawn the same way.

    With a ``field`` (an agar pad or a user's outline, see :func:`field_of`) the
    field of view is ``field.width_um x field.height_um`` from ``field.origin_um`` in
    the cells' coordinates instead; there is no device except the walls of
    ``field.walls_um`` (PDMS of ``field.wall_thickness_um``), media fills the rest
    (an agar pad: agar everywhere the cells are not), and ``field.depth_um`` is the
    optical depth.

    Parameters
    ----------
    cells
        Any object with equal-length 1-D arrays ``ids`` (>= 1, unique), ``x_um``
        (across the trench from its left wall), ``y_um`` (along the trench from the
        closed end), ``angle_rad`` (0 = along the trench), ``length_um`` (pole to
        pole) and ``width_um``.
    trench
        Trench geometry (width, length, depth, margin).
    microscope
        Gives the camera pixel size in the sample plane.
    render
        Gives the upsampling factor and the border (PSF radius).
    curvature
        Optional mapping ``cell id -> (a_um, b, c)`` of eq. 1 (see
        :func:`spherocylinder_distance` for the units); cells not in it are straight.
    field
        A non-trench field of view (:class:`Field`); ``trench`` is then not used.
    trench_origin_um
        Position ``(x, y)`` of the trench's top-left corner (left wall, closed end)
        in the field of view, in um from its top-left corner; the cells' coordinates
        stay relative to the trench. Default ``(margin_um, shown_top_um)``: the trench
        centred between equal side margins. Trench only (not with ``field``).
    camera_shape
        ``(rows, columns)`` of the camera image, for a field of view other than the
        trench plus its margins (e.g. a crop of a real recording, see
        :func:`~napari_symbac.fit.fit_scene`); ``trench.length_um`` and
        ``trench.margin_um`` then do not set the size. Trench only.

    Returns
    -------
    Scene
    """
    require_argument(microscope, Microscope, "draw_scene(microscope=...)")
    require_argument(render, RenderSettings, "draw_scene(render=...)")
    if field is None:
        require_argument(trench, TrenchGeometry, "draw_scene(trench=...)")
    ids = np.asarray(getattr(cells, "ids", None))
    if ids.ndim != 1:
        raise ValueError(f"cells.ids must be a 1-D array, got shape {ids.shape}")
    n = ids.shape[0]
    if n and not np.issubdtype(ids.dtype, np.integer):
        raise ValueError(f"cells.ids must be integers, got dtype {ids.dtype}")
    ids = ids.astype(np.int64)
    if n and (ids.min() < 1 or ids.max() > _MAX_ID):
        raise ValueError(
            f"cell ids must be in 1..{_MAX_ID} (uint32 labels), got {ids.min()}..{ids.max()}"
        )
    if np.unique(ids).size != n:
        raise ValueError("cell ids must be unique within a frame")
    x = _column(cells, "x_um", n)
    y = _column(cells, "y_um", n)
    angle = _column(cells, "angle_rad", n)
    length = _column(cells, "length_um", n)
    width = _column(cells, "width_um", n)
    if n and np.any(width <= 0):
        raise ValueError("cell widths must be positive")
    if n and np.any(length < width * (1 - 1e-9)):
        bad = ids[length < width * (1 - 1e-9)]
        raise ValueError(
            f"cells {bad.tolist()} are shorter (pole to pole) than they are wide: a "
            f"spherocylinder needs length_um >= width_um"
        )
    curv = _check_curvature(curvature)

    u = render.upsample
    border = render.psf_radius_px
    cam_px = microscope.pixel_size_um
    px = cam_px / u
    if field is None:
        m, top = trench.margin_um, trench.shown_top_um
        off_x, off_y = m, top
        rows = round((trench.length_um + top) / cam_px)
        cols = round((trench.width_um + 2 * m) / cam_px)
        if trench_origin_um is not None:
            off_x, off_y = (float(v) for v in trench_origin_um)
            if not (math.isfinite(off_x) and math.isfinite(off_y)):
                raise ValueError(f"trench_origin_um must be finite, got {trench_origin_um!r}")
        if camera_shape is not None:
            rows, cols = (int(v) for v in camera_shape)
        depth_um = trench.depth_um
    else:
        if trench_origin_um is not None or camera_shape is not None:
            raise ValueError("trench_origin_um and camera_shape place a trench, not a field")
        if not isinstance(field, Field):
            raise ValueError(f"field must be a scene.Field, got {type(field).__name__}")
        off_x, off_y = -field.origin_um[0], -field.origin_um[1]
        rows = round(field.height_um / cam_px)
        cols = round(field.width_um / cam_px)
        depth_um = field.depth_um
    if rows < 1 or cols < 1:
        raise ValueError(f"the field of view is smaller than one camera pixel ({cam_px} um)")
    shape = (rows * u + 2 * border, cols * u + 2 * border)
    if shape[0] * shape[1] > MAX_RENDER_PIXELS:
        # found as a user: a 100000 um trench or a 6500 um pad said only "reduce upsample
        # or size", naming no setting
        what = (
            f"the trench ({trench.length_um:g} x {trench.width_um:g} um)"
            if field is None
            else f"the field ({field.width_um:g} x {field.height_um:g} um)"
        )
        raise ValueError(
            f"{what} is drawn as {shape[0]:,} x {shape[1]:,} render pixels ({rows:,} x "
            f"{cols:,} camera pixels of {cam_px:g} um, x upsample {u}, plus a PSF border of "
            f"{border} px each side), more than {MAX_RENDER_PIXELS / 1e6:.0f} M: make it "
            "smaller, or lower upsample or psf_radius_px"
        )
    # Physical coordinates of render-pixel centres, origin at the top-left of the field of view.
    yc = (np.arange(shape[0]) - border + 0.5) * px
    xc = (np.arange(shape[1]) - border + 0.5) * px
    if field is None:
        trench_frac, device, device_fp = _trench_images(
            shape, border, px, off_x, off_y, trench.width_um, trench.closed_end
        )
    else:
        trench_frac, device = field_images(field, shape, border, px)
        device_fp = _device_fingerprint(field, shape, border, px)

    cells_frac, labels = rasterise_cells(
        xc,
        yc,
        px,
        border,
        trench_frac,
        depth_um,
        ids,
        (off_x + x, off_y + y),
        angle,
        length,
        width,
        curv,
        closed=field is None or bool(field.walls_um),
    )
    for image in (cells_frac, labels, ids):
        image.setflags(write=False)
    # Every image is C-contiguous, finite, of the right dtype and shape by construction;
    # the media image, and uint32 labels from uint16 ones, are made when first read.
    pending = {"media": functools.partial(media_fraction, trench_frac, cells_frac)}
    if labels.dtype != np.uint32:
        pending["labels"] = functools.partial(np.asarray, labels, np.uint32)
    scene = Scene._unchecked(
        pending,
        cells=cells_frac,
        device=device,
        labels=labels,
        border_px=border,
        upsample=u,
        camera_shape=(rows, cols),
        pixel_size_um=px,
        depth_um=depth_um,
        cell_ids=ids,
    )
    # The device image is the cached, read-only array of this geometry: reuse its hash.
    object.__setattr__(scene, "_known_fingerprints", {"device": device_fp})
    if labels.dtype != np.uint32:
        object.__setattr__(scene, "_narrow_labels", labels)
    # media = open - cells exactly here (and cells = 0 where open = 0): bulk rendering
    # convolves the open and device fractions once per geometry (optics.static).
    # ``replace_cells`` / ``replace_media`` copies do not carry it.
    object.__setattr__(scene, "_open_fraction", trench_frac)
    return scene
