"""Static geometry of a run: walls, where cells start, where they leave.

Four layouts (``SimulationSettings.geometry``):

* ``"trench"``: a mother-machine trench, closed at the top (y = 0), open at the
  bottom (y = length); 1D growth, or double loading when it is too wide
  (supplement section 2).
* ``"chamber"``: the same walls with a wide trench, founders spread across it, the
  flow channel at the open end (section 13.1).
* ``"agar_pad"``: no walls, a field of view the colony grows in (section 13.2).
* ``"outline"``: the user's own device, polylines or a DXF drawing.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from napari_symbac.settings import AgarPadGeometry, OutlineGeometry, SimulationSettings

__all__ = ["Layout", "make_layout", "read_dxf_walls"]

#: Thickness given to the trench's walls in the physics (um); thick walls cannot be
#: tunnelled through by a fast-growing stack.
TRENCH_WALL_UM = 1.0
#: Half-thickness of the walls of a user's outline (um); the drawn line is its centre.
OUTLINE_WALL_RADIUS_UM = 0.05


@dataclass(frozen=True, eq=False)
class Layout:
    """Everything about a geometry the simulator needs.

    Attributes
    ----------
    walls_um
        Inner wall surfaces as polylines (``(k, 2)`` arrays of ``(x, y)``) for drawing.
    segments_um
        Physics walls as ``(x0, y0, x1, y1, radius)`` capsules.
    exit_box_um
        ``(x_min, y_min, x_max, y_max)``: a cell whose centre leaves it is removed.
    founders
        ``(x, y, angle)`` of each founder cell.
    gravity_centre_um
        For the agar pad, the point gravity pulls to; ``None`` means "towards y = 0".
    max_width_um
        Widest a cell may be drawn (fits the trench), or ``inf``.
    box_walls_um
        ``(left, right)`` x of the side walls of a trench or chamber (closed end at
        y = 0), or ``None``.
    gravity_centres_um
        Agar pad: the colony centres and scattered founders' places; gravity pulls
        each cell towards the nearest (empty: ``gravity_centre_um`` alone).
    flow
        How growth pushes cells: ``"axial"`` along the trench from its closed end, or
        ``"radial"`` out from the colony's centroid, or ``"none"`` (contacts only).
    """

    walls_um: tuple[np.ndarray, ...]
    segments_um: tuple[tuple[float, float, float, float, float], ...]
    exit_box_um: tuple[float, float, float, float]
    founders: tuple[tuple[float, float, float], ...]
    gravity_centre_um: tuple[float, float] | None
    max_width_um: float
    flow: str = "axial"
    box_walls_um: tuple[float, float] | None = None
    gravity_centres_um: tuple[tuple[float, float], ...] = ()


def _row(centre_x: float, y: float, n: int, spacing: float) -> list[tuple[float, float]]:
    return [(centre_x + (i - (n - 1) / 2) * spacing, y) for i in range(n)]


def make_layout(settings: SimulationSettings, rng: np.random.Generator) -> Layout:
    """Build the :class:`Layout` of ``settings.geometry``.

    Parameters
    ----------
    settings
        The run's settings.
    rng
        Draws the founders' small initial tilts (agar pad: their orientation).
    """
    s = settings
    n = s.n_founders
    first_len = 0.75 * s.cell_max_length_um
    if s.geometry in ("trench", "chamber"):
        w, length = s.trench.width_um, s.trench.length_um
        t = TRENCH_WALL_UM
        segments = (
            (-t, length, -t, -t, t),
            (-t, -t, w + t, -t, t),
            (w + t, -t, w + t, length, t),
        )
        walls = (np.array([[0.0, length], [0.0, 0.0], [w, 0.0], [w, length]]),)
        if s.geometry == "trench":
            step = first_len + 0.1
            spots = [(w / 2, 0.05 + first_len / 2 + i * step) for i in range(n)]
        else:
            per_row = max(1, int(w // (s.cell_width_um * 1.5)))
            spots = []
            for i in range(n):
                row, col = divmod(i, per_row)
                in_row = min(per_row, n - row * per_row)
                x = w / 2 + (col - (in_row - 1) / 2) * w / in_row
                spots.append((x, 0.05 + first_len / 2 + row * (first_len + 0.1)))
        if spots[-1][1] + first_len / 2 > length:
            raise ValueError(
                f"SimulationSettings.n_founders={n} cells do not fit in a trench of "
                f"length_um={length}: use fewer founders or a longer trench"
            )
        founders = tuple((x, y, float(rng.uniform(-0.01, 0.01))) for x, y in spots)
        # A cell that somehow passes a wall is removed rather than left outside.
        exit_box = (-t, -t, w + t, length)
        flow = "axial" if s.geometry == "trench" else "radial"
        return Layout(walls, segments, exit_box, founders, None, w - 0.02, flow, (0.0, w))

    if s.geometry == "agar_pad":
        pad = s.agar_pad
        fw, fh = pad.field_width_um, pad.field_height_um
        spots, centres = _agar_pad_spots(pad, n, s.cell_max_length_um, rng)
        founders = tuple((x, y, float(rng.uniform(-math.pi, math.pi))) for x, y in spots)
        return Layout(
            (),
            (),
            (0.0, 0.0, fw, fh),
            founders,
            (fw / 2, fh / 2),
            math.inf,
            "none",
            gravity_centres_um=centres,
        )

    # outline
    lines = outline_polylines_um(s.outline)
    points = np.concatenate(lines)
    (x0, y0), (x1, y1) = points.min(axis=0), points.max(axis=0)
    m = s.outline.exit_margin_um
    r = OUTLINE_WALL_RADIUS_UM
    segments = tuple(
        (float(a[0]), float(a[1]), float(b[0]), float(b[1]), r)
        for line in lines
        for a, b in itertools.pairwise(line)
        if not np.allclose(a, b)
    )
    if s.outline.founders_um:
        spots = list(s.outline.founders_um)
    else:
        spots = _row((x0 + x1) / 2, (y0 + y1) / 2, n, s.cell_width_um * 1.5)
    founders = tuple((float(x), float(y), float(rng.uniform(-0.01, 0.01))) for x, y in spots)
    return Layout(
        tuple(lines), segments, (x0 - m, y0 - m, x1 + m, y1 + m), founders, None, math.inf, "radial"
    )


def outline_polylines_um(outline: OutlineGeometry) -> list[np.ndarray]:
    """The wall polylines of an :class:`~napari_symbac.settings.OutlineGeometry` in um."""
    if outline.dxf_path is not None:
        return read_dxf_walls(
            outline.dxf_path, unit_um=outline.dxf_unit_um, layer=outline.dxf_layer
        )
    return [np.asarray(line, dtype=float) for line in outline.polylines_um]


def read_dxf_walls(
    path: str | Path,
    *,
    unit_um: float = 1.0,
    layer: str | None = None,
    tolerance_um: float = 0.02,
) -> list[np.ndarray]:
    """Read the walls of a device drawing (DXF) as polylines in um.

    LINE, LWPOLYLINE, POLYLINE, ARC, CIRCLE, ELLIPSE and SPLINE entities of the
    model space are flattened to polylines (curves to within ``tolerance_um``),
    scaled by ``unit_um`` and flipped so that y runs down the image rows with the
    origin at the top-left corner of the drawing's bounding box.

    Raises
    ------
    ImportError
        If ``ezdxf`` (the ``[dxf]`` extra) is not installed.
    OSError
        If the file cannot be read.
    ValueError
        If the drawing is not valid DXF or holds no usable entities.
    """
    try:
        import ezdxf
        from ezdxf import path as ezpath
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError(
            "reading a DXF device outline needs ezdxf: pip install 'napari-symbac[dxf]'"
        ) from err
    path = Path(path)
    if not path.is_file():
        raise OSError(f"OutlineGeometry.dxf_path: DXF file {path} does not exist")
    try:
        doc = ezdxf.readfile(path)
    except ezdxf.DXFStructureError as err:
        raise ValueError(
            f"OutlineGeometry.dxf_path: {path} is not a valid DXF file: {err}"
        ) from err
    kinds = "LINE LWPOLYLINE POLYLINE ARC CIRCLE ELLIPSE SPLINE"
    query = doc.modelspace().query(kinds if layer is None else f'{kinds}[layer=="{layer}"]')
    lines = []
    for entity in query:
        flat = ezpath.make_path(entity).flattening(tolerance_um / unit_um)
        pts = np.array([(v.x, v.y) for v in flat], dtype=float) * unit_um
        if len(pts) >= 2:
            lines.append(pts)
    if not lines:
        where = "" if layer is None else f" on layer {layer!r}"
        raise ValueError(
            f"OutlineGeometry.dxf_path: {path} has no LINE/POLYLINE/ARC/CIRCLE entities{where} "
            "to use as walls"
        )
    allpts = np.concatenate(lines)
    x0, y1 = allpts[:, 0].min(), allpts[:, 1].max()
    return [np.column_stack([p[:, 0] - x0, y1 - p[:, 1]]) for p in lines]


def _grid(centre: tuple[float, float], n: int, spacing: float) -> list[tuple[float, float]]:
    side = math.ceil(math.sqrt(n))
    out = []
    for i in range(n):
        row, col = divmod(i, side)
        out.append(
            (
                centre[0] + (col - (side - 1) / 2) * spacing,
                centre[1] + (row - (side - 1) / 2) * spacing,
            )
        )
    return out


def _agar_pad_spots(
    pad: AgarPadGeometry, n: int, max_length_um: float, rng: np.random.Generator
) -> tuple[list[tuple[float, float]], tuple[tuple[float, float], ...]]:
    """Founder positions on an agar pad, and the colony centres and scattered places.

    One colony without scattered cells keeps the centred grid (no random draw).
    Otherwise colony centres and scattered cells are drawn uniformly inside the
    field's margin by rejection (``colony_separation_um`` from colony centres, half
    of it between scattered cells); each colony's founders form a small grid
    ``founder_spacing_um`` apart around its centre.
    """
    fw, fh = pad.field_width_um, pad.field_height_um
    spacing = pad.founder_spacing_um or max_length_um
    if pad.n_colonies == 1 and pad.scattered_cells == 0:
        return _grid((fw / 2, fh / 2), n, spacing), ((fw / 2, fh / 2),)
    m = pad.edge_margin_um
    placed: list[tuple[float, float, float]] = []  # x, y, exclusion radius

    def draw(radius: float, what: str) -> tuple[float, float]:
        for _ in range(2000):
            x, y = rng.uniform(m, fw - m), rng.uniform(m, fh - m)
            if all(math.hypot(x - px, y - py) >= max(radius, pr) for px, py, pr in placed):
                placed.append((x, y, radius))
                return x, y
        raise ValueError(
            f"cannot place {what} on a {fw} x {fh} um pad with colony_separation_um="
            f"{pad.colony_separation_um}: use fewer colonies or scattered cells, a smaller "
            "separation or a larger field"
        )

    spots: list[tuple[float, float]] = []
    shares = [n // pad.n_colonies + (i < n % pad.n_colonies) for i in range(pad.n_colonies)]
    for i, share in enumerate(shares):
        centre = draw(pad.colony_separation_um, f"colony {i + 1} of {pad.n_colonies}")
        spots.extend(_grid(centre, share, spacing))
    for i in range(pad.scattered_cells):
        spots.append(
            draw(pad.colony_separation_um / 2, f"scattered cell {i + 1} of {pad.scattered_cells}")
        )
    return spots, tuple((x, y) for x, y, _ in placed)

