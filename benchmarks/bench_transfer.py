"""Synthetic-to-real segmentation: does a network trained only on calibrated data work?

Run: ``python benchmarks/bench_transfer.py [--data colicoords|colicoords-brightfield|omnipose]
[--quick] [--out DIR]``. Needs torch (CPU is enough; CUDA is used when present).

Protocol (fixed; the same for every training set):

* **real test data** with instance masks: the 10 ColiCoords ds1 fluorescence fields
  (512 x 512, 80 nm pixels assumed; binary masks split into connected components), or
  the 3 Omnipose phase-contrast colonies (8-bit, pixel size from the masks' widths);
  ``colicoords-brightfield``: the same ten fields and masks in bright field (flattened,
  9-12 % of the pixels clipped at 65535), calibrated as bright field;
* **calibrated**: :func:`napari_symbac.calibrate.calibrate` given only what a user knows
  (the microscope file and the modality). ColiCoords: the image of field 1 without its
  masks (the fit's own segmentation). Omnipose: the pixel size is not known, so the
  masks of the calibration image give it (cell width 1 um) and the dense-colony fit
  uses them; the three colonies are imaged at scales 2.3x apart (7.5-17.4 px per cell
  width), so each is calibrated from itself: its masks set the pixel size, cell sizes
  and layout of its synthetic data, but the network never sees them;
  then ``export_settings`` -> ``PipelineSource`` items (faint cells dropped);
* **calibrated with field 1's masks** (ColiCoords only): what a user with a few
  annotated cells has: ``calibrate`` given field 1's image *and* masks, which also
  measures how far the masks' outline lies outside the fitted model cells and grows the
  exported masks by it (``mask_dilation_um``); judged on fields 2-10 only (field 1's
  masks were seen), beside the real-annotation network's numbers on the same fields;
* **defaults**: the tool's defaults with the user's microscope, fluorescence
  intensities of the GUI's modality switch (3000 / 150 ADU), an agar-pad colony;
* **real annotations**: the same network trained on the other real images with their
  masks (leave-one-image-out cross-validation, each image tested by the fold that did
  not train on it);
* **Otsu + watershed**: Gaussian smoothing (1 px), Otsu threshold with the modality's
  polarity, watershed of the distance transform from its h-maxima (h = 2 px); on all
  fields and (ColiCoords) on fields 2-10, beside the row calibrated with field 1's masks;
* objects smaller than 0.25 um^2 are removed from every method's output; ColiCoords:
  so are objects that touch the image border (:func:`drop_border_objects`): its
  annotations are filtered probability maps from which the objects cut by the border
  were dropped (0 of 52 cells touch it, while the fields show cut cells), so a
  prediction there cannot be judged (Omnipose: the colonies lie inside the frame, no
  such convention; its rule is unchanged);
* the network: a 3-level U-Net (8-16-32 channels) predicting background / cell
  interior / cell boundary, trained on random 96 x 96 tiles (half centred on a cell;
  flips, rotations) of 1-99 percentile normalised images, Adam 2e-3, a fixed number of
  steps and batch size and seed; instances = connected interiors grown over the
  foreground by watershed;
* **metrics** over all test images: pixel IoU of the foreground, F1 at matched IoU
  >= 0.5, mean IoU of matched cells, and the mean width and length bias (um) of matched
  cells (predicted minus annotated, widths as twice the largest inscribed radius minus
  a pixel, lengths as the largest Feret diameter plus a pixel).

``--packing`` measures instead, for each Omnipose colony, the real masks and the
ground-truth masks of its calibrated synthetic images (and of the same settings
without the compaction calibrate chose: gravity 0, 15 physics iterations): the cell
fraction of the colonies, the seams between neighbouring cells, cell sizes and
curvature, the overlap depth of the simulated cells; prints a markdown table.

``--seeds`` sets the seeds of the calibrated rows (default 0 1; each seed is one
synthetic training set and one network).

``--baseline-seeds`` sets the seeds of the real-annotation networks (default 0; one
set of leave-one-image-out folds per seed, named ``(seed N)`` when more than one), so
that the comparison is of means over seeds on both sides; a second table gives each
method's mean and s.d. of F1 and width bias over its seeds.

``--no-baselines`` skips the real-annotation folds and the defaults row (neither
depends on ``calibrate``; the folds are most of the run's time).

Prints a markdown table (and writes ``results.json`` and pictures to ``--out``); it
asserts nothing. ``--quick`` runs the same code on tiny sizes (the test of this file).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

ROOT = Path(__file__).resolve().parents[1]


def real_dir() -> Path:
    """``../shared/data/real`` beside the checkout, or ``$NAPARI_SYMBAC_REAL_DATA``."""
    return Path(os.environ.get("NAPARI_SYMBAC_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))

#: GUI defaults of the modality switch (``_widgets/_recording.py``).
MODALITY_DEFAULTS = {
    "fluorescence": {"cell_intensity": 3000.0, "media_intensity": 150.0, "device_intensity": 60.0},
    "brightfield": {
        "cell_intensity": 2500.0, "media_intensity": 2600.0, "device_intensity": 2300.0
    },
}
#: Wavelength the user's microscope file gives (um): the ColiCoords stain's emission, and
#: the middle of a halogen lamp's band for bright field and phase contrast.
WAVELENGTH_UM = {"fluorescence": 0.53, "brightfield": 0.55, "phase": 0.55}


@dataclass(frozen=True)
class Budget:
    """Sizes of one benchmark run."""

    steps: int = 500
    batch: int = 8
    tile: int = 96
    n_synthetic: int = 48
    crop_px: int = 256
    max_fields: int | None = None
    image_px: int | None = None  # crop real images to this (quick runs)


QUICK = Budget(steps=4, batch=2, tile=64, n_synthetic=3, crop_px=96, max_fields=3, image_px=160)


# ----------------------------------------------------------------------------- data


@dataclass(frozen=True)
class RealImage:
    name: str
    image: np.ndarray  # float32, raw units
    masks: np.ndarray  # int32 instance ids
    pixel_size_um: float
    border_annotated: bool = True  # False: no cell cut by the border is annotated


def load_colicoords(
    budget: Budget, modality: str = "fluorescence"
) -> tuple[list[RealImage], str]:
    """The ds1 fields in ``modality`` (``"fluorescence"`` or ``"brightfield"``: the same
    cells, the same masks)."""
    import tifffile

    folder = real_dir() / "colicoords" / "test_data" / "ds1"
    images = []
    for path in sorted((folder / modality).glob("*.tif"))[: budget.max_fields]:
        image = tifffile.imread(path)
        binary = tifffile.imread(folder / "binary" / f"{path.stem}_Probabilities_filtered.tif")
        masks, _ = ndimage.label(binary > 0)
        if budget.image_px:
            image, masks = image[: budget.image_px, : budget.image_px], masks[
                : budget.image_px, : budget.image_px
            ]
        images.append(RealImage(path.stem, image, masks.astype(np.int32), 0.08, False))
    return images, modality



#: Packages whose versions a result depends on (written beside it: found rerunning the
#: Omnipose rows, seed 0 gave 0.789 where the same commit had given 0.872 two days
#: before, in an environment installed anew since, whose versions no file recorded).
RESULT_PACKAGES = ("numpy", "scipy", "scikit-image", "pymunk", "numba", "torch")


def package_versions() -> dict[str, str]:
    """The installed version of each of :data:`RESULT_PACKAGES`."""
    from importlib.metadata import version

    return {name: version(name) for name in RESULT_PACKAGES}


def load_omnipose(budget: Budget) -> tuple[list[RealImage], str]:
    import imageio.v3 as iio
    import tifffile

    from napari_symbac.fit.masks import estimate_pixel_size_um

    folder = real_dir() / "omnipose"
    images = []
    for path in sorted(folder.glob("Sample*.png"))[: budget.max_fields]:
        data = np.asarray(iio.imread(path))
        image = data[..., 0] if data.ndim == 3 else data
        masks = tifffile.imread(folder / f"{path.stem}_cp_masks.tif").astype(np.int32)
        if budget.image_px:
            r0, c0 = (np.array(masks.shape) - budget.image_px) // 2
            window = (slice(r0, r0 + budget.image_px), slice(c0, c0 + budget.image_px))
            image, masks = image[window], masks[window]
        images.append(RealImage(path.stem, image, masks, estimate_pixel_size_um(masks, 1.0)))
    return images, "phase"


#: The real data sets: name -> loader.
LOADERS = {
    "colicoords": load_colicoords,
    "colicoords-brightfield": lambda budget: load_colicoords(budget, "brightfield"),
    "omnipose": load_omnipose,
}


def normalise(image: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(image, [1, 99])
    return ((np.asarray(image, np.float32) - lo) / max(hi - lo, 1e-6)).astype(np.float32)


def targets(labels: np.ndarray) -> np.ndarray:
    """0 background, 1 cell interior, 2 cell boundary (inner pixels touching another id)."""
    labels = np.asarray(labels)
    grown = ndimage.grey_dilation(labels, size=3)
    shrunk = ndimage.grey_erosion(labels, size=3)
    edge = (labels > 0) & ((grown != labels) | (shrunk != labels))
    out = (labels > 0).astype(np.int64)
    out[edge] = 2
    return out


# ------------------------------------------------------------------- training sets


def synthetic_pairs(settings, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    from napari_symbac.export.dataset import PipelineSource

    source = PipelineSource(settings)
    pairs = []
    for unit in range(n):
        item = source.make_unit(unit)[0]
        pairs.append((normalise(item.image), targets(item.labels)))
    return pairs


def calibrated_settings(
    reference: RealImage, modality: str, budget: Budget, seed: int, with_masks: bool = False
):
    from napari_symbac.calibrate import calibrate, export_settings
    from napari_symbac.settings import Microscope

    if modality != "phase":  # what the user knows: the microscope and modality
        microscope = Microscope(
            pixel_size_um=0.08, wavelength_um=WAVELENGTH_UM[modality], modality=modality
        )
        cal = calibrate(
            reference.image,
            masks=reference.masks if with_masks else None,
            microscope=microscope,
            crop_px=budget.crop_px,
        )
    else:  # pixel size unknown: from the calibration image's masks and a 1 um width
        microscope = Microscope(wavelength_um=0.55, modality=modality)
        cal = calibrate(
            reference.image,
            masks=reference.masks,
            microscope=microscope,
            cell_width_um=1.0,
            crop_px=min(budget.crop_px, 160),
            max_evaluations=25 if budget is not QUICK else 4,
        )
    return cal, export_settings(cal, n_items=budget.n_synthetic, seed=seed)


def default_settings(reference: RealImage, modality: str, budget: Budget, seed: int):
    from napari_symbac.export.dataset import ExportSettings
    from napari_symbac.export.visibility import Visibility
    from napari_symbac.settings import Microscope, PipelineSettings, RenderSettings

    base = PipelineSettings()
    microscope = Microscope(
        pixel_size_um=reference.pixel_size_um,
        wavelength_um=WAVELENGTH_UM[modality],
        modality=modality,
    )
    render = base.render
    if modality != "phase":
        render = dataclasses.replace(
            render, ring_contrast=0.0, psf_offset=0.0, **MODALITY_DEFAULTS[modality]
        )
    else:
        render = RenderSettings()
    side_um = max(reference.image.shape) * reference.pixel_size_um
    simulation = dataclasses.replace(
        base.simulation,
        geometry="agar_pad",
        agar_pad=dataclasses.replace(
            base.simulation.agar_pad, field_width_um=side_um, field_height_um=side_um
        ),
        n_frames=40 if budget is not QUICK else 6,
    )
    pipeline = dataclasses.replace(
        base, simulation=simulation, microscope=microscope, render=render,
        camera=dataclasses.replace(base.camera, bit_depth=16),
    )
    return ExportSettings(
        n_items=budget.n_synthetic,
        seed=seed,
        n_simulations=min(budget.n_synthetic, 16),
        first_frame=simulation.n_frames // 2,
        pipeline=pipeline,
        visibility=Visibility(action="drop"),
    )


# ---------------------------------------------------------------------------- network


def make_unet(torch):
    nn = torch.nn

    def block(cin, cout):
        return nn.Sequential(
            nn.Conv2d(cin, cout, 3, padding=1), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
            nn.Conv2d(cout, cout, 3, padding=1), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
        )

    class UNet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.e1, self.e2, self.e3 = block(1, 8), block(8, 16), block(16, 32)
            self.pool = nn.MaxPool2d(2)
            self.u2 = nn.ConvTranspose2d(32, 16, 2, stride=2)
            self.d2 = block(32, 16)
            self.u1 = nn.ConvTranspose2d(16, 8, 2, stride=2)
            self.d1 = block(16, 8)
            self.head = nn.Conv2d(8, 3, 1)

        def forward(self, x):
            a = self.e1(x)
            b = self.e2(self.pool(a))
            c = self.e3(self.pool(b))
            d = self.d2(torch.cat([self.u2(c), b], 1))
            return self.head(self.d1(torch.cat([self.u1(d), a], 1)))

    return UNet()


def _tile(image, target, size, rng):
    """A random tile (padded by reflection when the image is smaller), flipped/rotated;
    half of the tiles are centred on a random cell pixel (sparse fields are mostly
    background)."""
    pad = [(0, max(0, size - s)) for s in image.shape]
    if any(p[1] for p in pad):
        image, target = np.pad(image, pad, mode="reflect"), np.pad(target, pad)
    r = int(rng.integers(0, image.shape[0] - size + 1))
    c = int(rng.integers(0, image.shape[1] - size + 1))
    if rng.random() < 0.5 and target.any():
        rows, cols = np.nonzero(target)
        k = int(rng.integers(rows.size))
        r = int(np.clip(rows[k] - size // 2, 0, image.shape[0] - size))
        c = int(np.clip(cols[k] - size // 2, 0, image.shape[1] - size))
    x, y = image[r : r + size, c : c + size], target[r : r + size, c : c + size]
    k = int(rng.integers(0, 4))
    x, y = np.rot90(x, k), np.rot90(y, k)
    if rng.random() < 0.5:
        x, y = x[:, ::-1], y[:, ::-1]
    return np.ascontiguousarray(x), np.ascontiguousarray(y)


def train(pairs, budget: Budget, seed: int):
    """Train the U-Net on ``(normalised image, target)`` pairs; returns the model."""
    import torch

    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    device = "cuda" if torch.cuda.is_available() else "cpu"
    model = make_unet(torch).to(device)
    optimiser = torch.optim.Adam(model.parameters(), lr=2e-3)
    weights = torch.tensor([1.0, 1.0, 3.0], device=device)
    model.train()
    for _ in range(budget.steps):
        tiles = [_tile(*pairs[int(rng.integers(len(pairs)))], budget.tile, rng)
                 for _ in range(budget.batch)]
        x = torch.from_numpy(np.stack([t[0] for t in tiles])[:, None]).to(device)
        y = torch.from_numpy(np.stack([t[1] for t in tiles])).to(device)
        loss = torch.nn.functional.cross_entropy(model(x), y, weight=weights)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    model.eval()
    return model


def predict(model, image: np.ndarray) -> np.ndarray:
    """Class probabilities ``(3, Y, X)`` of a normalised image (padded to a multiple of 4)."""
    import torch

    h, w = image.shape
    ph, pw = (-h) % 4, (-w) % 4
    x = np.pad(image, ((0, ph), (0, pw)), mode="reflect")
    device = next(model.parameters()).device
    with torch.no_grad():
        out = torch.softmax(model(torch.from_numpy(x[None, None]).to(device)), 1)
    return out[0, :, :h, :w].cpu().numpy()


def instances_from_probabilities(prob: np.ndarray, min_area: int = 10) -> np.ndarray:
    """Seeds = connected interiors, grown over the foreground by watershed."""
    from skimage.segmentation import watershed

    cls = prob.argmax(0)
    foreground = cls > 0
    seeds, _ = ndimage.label(cls == 1)
    sizes = np.bincount(seeds.ravel())
    seeds[np.isin(seeds, np.flatnonzero(sizes < max(3, min_area // 3)))] = 0
    labels = watershed(-prob[1], seeds, mask=foreground)
    sizes = np.bincount(labels.ravel())
    labels[np.isin(labels, np.flatnonzero(sizes < min_area))] = 0
    return labels.astype(np.int32)


def drop_border_objects(labels: np.ndarray) -> np.ndarray:
    """``labels`` without the objects that touch the image border (set to 0)."""
    from napari_symbac.export.outline import border_ids

    out = np.array(labels)
    out[np.isin(out, border_ids(out))] = 0
    return out


def otsu_watershed(image: np.ndarray, modality: str, min_area: int = 10) -> np.ndarray:
    """Otsu foreground (polarity of the modality) split by a watershed of its distance
    transform from its h-maxima (h = 2 px: a rod's ridge is one seed, not many)."""
    from skimage.filters import threshold_otsu
    from skimage.morphology import h_maxima
    from skimage.segmentation import watershed

    smooth = ndimage.gaussian_filter(np.asarray(image, np.float64), 1.0)
    t = threshold_otsu(smooth)
    fg = smooth > t if modality == "fluorescence" else smooth < t
    fg = ndimage.binary_opening(fg, iterations=1)
    distance = ndimage.gaussian_filter(ndimage.distance_transform_edt(fg), 1.0)
    markers, _ = ndimage.label(h_maxima(distance, 2.0))
    labels = watershed(-distance, markers, mask=fg)
    sizes = np.bincount(labels.ravel())
    labels[np.isin(labels, np.flatnonzero(sizes < min_area))] = 0
    return labels.astype(np.int32)


# ---------------------------------------------------------------------------- metrics


def _sizes_px(labels: np.ndarray) -> dict[int, tuple[float, float]]:
    from skimage.measure import regionprops

    out = {}
    for region in regionprops(labels):
        mask = np.pad(region.image, 1)
        width = 2.0 * ndimage.distance_transform_edt(mask).max() - 1.0
        out[region.label] = (width, region.feret_diameter_max + 1.0)
    return out


def match(truth: np.ndarray, pred: np.ndarray) -> dict[str, float | list]:
    """Pixel IoU, matches at IoU >= 0.5 (unique), their IoUs and size differences (px)."""
    t, p = truth > 0, pred > 0
    union = np.logical_or(t, p).sum()
    pixel_iou = float(np.logical_and(t, p).sum() / union) if union else 1.0
    n_true = len(np.unique(truth)) - (0 in truth)
    n_pred = len(np.unique(pred)) - (0 in pred)
    pairs = np.stack([truth.ravel(), pred.ravel()], 1)
    pairs = pairs[(pairs[:, 0] > 0) & (pairs[:, 1] > 0)]
    ious, dw, dl = [], [], []
    if pairs.size:
        keys, inter = np.unique(pairs, axis=0, return_counts=True)
        area_t = dict(zip(*np.unique(truth[truth > 0], return_counts=True), strict=True))
        area_p = dict(zip(*np.unique(pred[pred > 0], return_counts=True), strict=True))
        size_t, size_p = _sizes_px(truth), _sizes_px(pred)
        for (a, b), n in zip(keys, inter, strict=True):
            iou = n / (area_t[a] + area_p[b] - n)
            if iou >= 0.5:
                ious.append(float(iou))
                dw.append(size_p[b][0] - size_t[a][0])
                dl.append(size_p[b][1] - size_t[a][1])
    return {
        "pixel_iou": pixel_iou, "tp": len(ious), "fp": n_pred - len(ious),
        "fn": n_true - len(ious), "ious": ious, "dw_px": dw, "dl_px": dl,
    }


def summarise(results: list[dict], pixel_sizes: list[float]) -> dict[str, float]:
    tp = sum(r["tp"] for r in results)
    fp = sum(r["fp"] for r in results)
    fn = sum(r["fn"] for r in results)
    ious = [i for r in results for i in r["ious"]]
    dw = [d * px for r, px in zip(results, pixel_sizes, strict=True) for d in r["dw_px"]]
    dl = [d * px for r, px in zip(results, pixel_sizes, strict=True) for d in r["dl_px"]]
    return {
        "pixel_iou": float(np.mean([r["pixel_iou"] for r in results])),
        "f1": 2 * tp / max(2 * tp + fp + fn, 1),
        "precision": tp / max(tp + fp, 1),
        "recall": tp / max(tp + fn, 1),
        "matched_iou": float(np.mean(ious)) if ious else math.nan,
        "width_bias_um": float(np.mean(dw)) if dw else math.nan,
        "length_bias_um": float(np.mean(dl)) if dl else math.nan,
    }


# ------------------------------------------------------------------------------- run


def run(
    data: str,
    budget: Budget,
    out: Path | None,
    seeds=(0, 1),
    baselines: bool = True,
    baseline_seeds=(0,),
) -> list[dict]:
    images, modality = LOADERS[data](budget)
    px = [im.pixel_size_um for im in images]
    rows = []

    # the same smallest object for every method: 0.25 um^2 (a cell is >= ~1 um^2)
    min_area = [max(10, round(0.25 / p**2)) for p in px]

    def judged(im: RealImage, labels: np.ndarray) -> np.ndarray:
        return labels if im.border_annotated else drop_border_objects(labels)

    def evaluate(
        name: str, predict_one, seconds: float, note: str = "", fields=None
    ) -> None:
        fields = range(len(images)) if fields is None else fields
        results = [match(images[k].masks, judged(images[k], predict_one(k, images[k])))
                   for k in fields]
        summary = summarise(results, [px[k] for k in fields])
        rows.append({"method": name, **summary, "seconds": seconds, "note": note})
        print(f"  {name}: F1 {rows[-1]['f1']:.3f} ({seconds:.0f} s)", flush=True)

    # ColiCoords, calibrated with field 1's masks: judged on the other fields only
    masked_fields = list(range(1, len(images)))
    start = time.perf_counter()
    for fields, label in ((None, ""), (masked_fields, ", fields 2-10")):
        if fields is None or data.startswith("colicoords"):
            evaluate(
                f"Otsu + watershed{label}",
                lambda k, im: otsu_watershed(im.image, modality, min_area[k]),
                0.0,
                fields=fields,
            )

    # real annotations, leave-one-image-out; one set of folds per baseline seed
    for seed in baseline_seeds if baselines else ():
        start = time.perf_counter()
        fold_models = []
        for k in range(len(images)):
            pairs = [
                (normalise(im.image), targets(im.masks)) for j, im in enumerate(images) if j != k
            ]
            fold_models.append(train(pairs, budget, seed=seed))
        suffix = f" (seed {seed})" if len(baseline_seeds) > 1 else ""
        for fields, label in ((None, ""), (masked_fields, ", fields 2-10")):
            if fields is None or data.startswith("colicoords"):
                evaluate(
                    f"U-Net, real annotations (leave-one-image-out){label}{suffix}",
                    lambda k, im, fold_models=fold_models: instances_from_probabilities(
                        predict(fold_models[k], normalise(im.image)), min_area[k]
                    ),
                    time.perf_counter() - start,
                    f"{len(images)} folds",
                    fields,
                )
    pictures = {}
    # ColiCoords: field 1's image (no masks) calibrates every field; Omnipose: the three
    # colonies differ 2.3x in pixels per cell, so each calibrates itself
    reference_of = (
        [0] * len(images) if data.startswith("colicoords") else list(range(len(images)))
    )
    calibrations = {}
    for seed in seeds:
        start = time.perf_counter()
        models = {}
        for ref in sorted(set(reference_of)):
            if ref not in calibrations:
                calibrations[ref] = calibrated_settings(images[ref], modality, budget, 0)
            settings = calibrations[ref][1]
            settings = dataclasses.replace(settings, seed=seed)
            models[ref] = train(synthetic_pairs(settings, budget.n_synthetic), budget, seed)
            if seed == seeds[0]:
                pictures[f"synthetic_{images[ref].name}"] = synthetic_pairs(settings, 1)[0][0]
        evaluate(
            f"U-Net, calibrated synthetic only (seed {seed})",
            lambda k, im, models=models: instances_from_probabilities(
                predict(models[reference_of[k]], normalise(im.image)), min_area[k]
            ),
            time.perf_counter() - start,
            "; ".join(
                f"{images[r].name}: {c.method}, {c.measurements.n_cells} cells"
                for r, (c, _) in calibrations.items() if r != "masks"
            ),
        )
        if seed == seeds[0]:
            pictures["models"] = models
    for seed in seeds if data.startswith("colicoords") else ():
        start = time.perf_counter()
        if "masks" not in calibrations:
            calibrations["masks"] = calibrated_settings(
                images[0], modality, budget, 0, with_masks=True
            )
        cal, settings = calibrations["masks"]
        model = train(
            synthetic_pairs(dataclasses.replace(settings, seed=seed), budget.n_synthetic),
            budget,
            seed,
        )
        evaluate(
            f"U-Net, calibrated with field 1's masks, fields 2-10 (seed {seed})",
            lambda k, im, model=model: instances_from_probabilities(
                predict(model, normalise(im.image)), min_area[k]
            ),
            time.perf_counter() - start,
            f"mask outline {cal.mask_offset_um:+.3f} um, masks grown "
            f"{settings.mask_dilation_um:.3f} um",
            masked_fields,
        )
    start = time.perf_counter()
    default_models = {}
    for ref in sorted(set(reference_of)) if baselines else ():
        settings = default_settings(images[ref], modality, budget, 0)
        default_models[ref] = train(synthetic_pairs(settings, budget.n_synthetic), budget, 0)
    if baselines:
        evaluate(
            "U-Net, tool defaults (modality switched)",
            lambda k, im: instances_from_probabilities(
                predict(default_models[reference_of[k]], normalise(im.image)), min_area[k]
            ),
            time.perf_counter() - start,
        )
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / f"results_{data}.json").write_text(json.dumps(rows, indent=2))
        (out / f"versions_{data}.json").write_text(json.dumps(package_versions(), indent=2))
        _pictures(out, data, images, modality, pictures, reference_of, judged)
    return rows


def _pictures(out, data, images, modality, pictures, reference_of, judged) -> None:
    """real | U-Net (calibrated synthetic) outlines | Otsu outlines, and a synthetic image."""
    import imageio.v3 as iio

    from napari_symbac.calibrate.compare import montage

    k = len(images) - 1
    im = images[k]
    model = pictures["models"][reference_of[k]]
    pred = judged(im, instances_from_probabilities(
        predict(model, normalise(im.image)), max(10, round(0.25 / im.pixel_size_um**2))
    ))
    picture = montage(im.image, im.image, im.masks, pred)
    iio.imwrite(out / f"transfer_{data}_prediction.png", picture)
    preds = [
        judged(image, instances_from_probabilities(
            predict(pictures["models"][reference_of[j]], normalise(image.image)),
            max(10, round(0.25 / image.pixel_size_um**2)),
        ))
        for j, image in enumerate(images)
    ]
    gallery = false_positive_gallery(images, preds)
    if gallery is not None:
        iio.imwrite(out / f"transfer_{data}_false_positives.png", gallery)
    for key, value in pictures.items():
        if key.startswith("synthetic_"):
            ref = next(i for i in images if f"synthetic_{i.name}" == key)
            iio.imwrite(out / f"transfer_{data}_{key}.png", montage(ref.image, value))


def false_positives(truth: np.ndarray, pred: np.ndarray) -> list[int]:
    """Ids of the predicted objects that match no annotated cell at IoU >= 0.5."""
    out = []
    for index in np.unique(pred[pred > 0]):
        region = pred == index
        ids, inter = np.unique(truth[region & (truth > 0)], return_counts=True)
        best = max(
            (n / ((truth == i).sum() + region.sum() - n) for i, n in zip(ids, inter, strict=True)),
            default=0.0,
        )
        if best < 0.5:
            out.append(int(index))
    return out


def false_positive_gallery(
    images: list[RealImage], preds: list[np.ndarray], half_px: int = 32, columns: int = 8
) -> np.ndarray | None:
    """8-bit RGB tiles around every false positive (:func:`false_positives`), each
    image at its own 1-99.5 percentiles: annotations outlined blue, the false positive
    red; in image order. ``None`` when there is none."""
    from skimage.segmentation import find_boundaries

    tiles = []
    for im, pred in zip(images, preds, strict=True):
        lo, hi = np.percentile(im.image, [1, 99.5])
        grey = np.clip((np.asarray(im.image, np.float64) - lo) / max(hi - lo, 1e-9), 0, 1)
        pad = ((half_px, half_px), (half_px, half_px))
        grey, truth, pred_p = np.pad(grey, pad), np.pad(im.masks, pad), np.pad(pred, pad)
        for index in false_positives(im.masks, pred):
            rows, cols = np.nonzero(pred_p == index)
            r, c = int(rows.mean()), int(cols.mean())
            window = (slice(r - half_px, r + half_px), slice(c - half_px, c + half_px))
            rgb = np.repeat(grey[window][..., None], 3, axis=-1)
            rgb[find_boundaries(truth[window])] = (0.0, 0.6, 1.0)
            rgb[find_boundaries(pred_p[window] == index)] = (1.0, 0.2, 0.2)
            tiles.append(np.pad(rgb, ((0, 2), (0, 2), (0, 0)), constant_values=1.0))
    if not tiles:
        return None
    side = tiles[0].shape[0]
    n_rows = -(-len(tiles) // columns)
    grid = np.ones((n_rows * side, min(columns, len(tiles)) * side, 3))
    for k, tile in enumerate(tiles):
        grid[(k // columns) * side : (k // columns + 1) * side,
             (k % columns) * side : (k % columns + 1) * side] = tile
    return (255 * grid).astype(np.uint8)


def packing_rows(budget: Budget, n_images: int = 4) -> list[dict]:
    """Real against synthetic packing and cell shapes of every Omnipose colony
    (``--packing``): the real masks, ``n_images`` exported synthetic images of the
    calibrated settings, and of the same settings uncompacted (gravity 0, 15 physics
    iterations, as calibrate made them before it chose a gravity)."""
    from napari_symbac.calibrate.compaction import overlap_depths_um
    from napari_symbac.calibrate.measure import cell_curvatures_px, lengths_px, measure_packing
    from napari_symbac.export.dataset import PipelineSource, _simulation
    from napari_symbac.fit.masks import cell_widths_px

    images, modality = load_omnipose(budget)
    rows = []

    def row(name, masks_list, px, depths=None):
        packs = [measure_packing(m) for m in masks_list]
        gaps = np.concatenate([p.gaps_px for p in packs])
        lengths = np.concatenate([lengths_px(m) for m in masks_list]) * px
        widths = np.concatenate([cell_widths_px(m) for m in masks_list]) * px
        curv = np.concatenate([cell_curvatures_px(m) for m in masks_list]) / px
        return {
            "data": name,
            "cells": int(sum(len(np.unique(m)) - 1 for m in masks_list)),
            "cell_fraction": float(np.nanmean([p.cell_fraction for p in packs])),
            "seam_px": float(gaps.mean()) if gaps.size else math.nan,
            "seam_um": float(gaps.mean() * px) if gaps.size else math.nan,
            "touching": float((gaps == 0).mean()) if gaps.size else math.nan,
            "length_um": [float(q) for q in np.percentile(lengths, [25, 50, 75])],
            "width_um": [float(q) for q in np.percentile(widths, [25, 50, 75])],
            "curvature_per_um": [float(q) for q in np.percentile(curv, [50, 90])],
            "overlap_widths_p95": depths,
        }

    for im in images:
        cal, export = calibrated_settings(im, modality, budget, 0)
        px = cal.settings.microscope.pixel_size_um
        rows.append(row(f"{im.name} real", [im.masks], im.pixel_size_um))
        loose = dataclasses.replace(
            cal.settings,
            simulation=dataclasses.replace(cal.settings.simulation, gravity=0.0, phys_iters=15),
        )
        for label, pipeline in (
            ("synthetic, gravity 0 (before)", loose),
            (f"synthetic, gravity {cal.settings.simulation.gravity:g} (calibrate)", cal.settings),
        ):
            settings = dataclasses.replace(export, pipeline=pipeline)
            source = PipelineSource(settings)
            masks = [source.make_unit(u)[0].labels.astype(np.int32) for u in range(n_images)]
            depths = []
            for u in range(min(n_images, settings.n_simulations)):
                last = _simulation(pipeline, settings.seed, u).frames[-1]
                d = overlap_depths_um(last) / float(np.median(last.width_um))
                depths.append(float(np.percentile(d, 95)) if d.size else 0.0)
            rows.append(row(f"{im.name} {label}", masks, px, float(np.mean(depths))))
        print(f"  {im.name}: " + "; ".join(cal.notes[-1:]), flush=True)
    return rows


def packing_table(rows: list[dict]) -> str:
    lines = [
        "| data | cells | cell fraction of colonies | seam (px) | seam (um) | pairs touching "
        "| length (um, quartiles) | width (um, quartiles) | curvature (1/um, median, 90 %) "
        "| overlap (95 %, widths) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        q = "{:.2f}-{:.2f}-{:.2f}"
        overlap = "" if r["overlap_widths_p95"] is None else f"{r['overlap_widths_p95']:.2f}"
        lines.append(
            f"| {r['data']} | {r['cells']} | {r['cell_fraction']:.3f} | {r['seam_px']:.2f} | "
            f"{r['seam_um']:.3f} | {r['touching']:.2f} | {q.format(*r['length_um'])} | "
            f"{q.format(*r['width_um'])} | {r['curvature_per_um'][0]:.3f}, "
            f"{r['curvature_per_um'][1]:.3f} | {overlap} |"
        )
    return "\n".join(lines)


def table(rows: list[dict]) -> str:
    lines = [
        "| training data | pixel IoU | F1@0.5 | precision | recall | matched IoU | width bias (um) "
        "| length bias (um) | time (s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['method']} | {r['pixel_iou']:.3f} | {r['f1']:.3f} | {r['precision']:.3f} | "
            f"{r['recall']:.3f} | {r['matched_iou']:.3f} | {r['width_bias_um']:+.3f} | "
            f"{r['length_bias_um']:+.3f} | {r['seconds']:.0f} |"
        )
    return "\n".join(lines)


def seed_means(rows: list[dict]) -> list[dict]:
    """The rows of one method over its seeds (names ending in `` (seed N)``): mean and
    sample s.d. of F1@0.5 and of the width bias (over the seeds whose network matched a
    cell), with the number of seeds. Methods with one seed are left out: a mean of one
    is the row itself."""
    groups: dict[str, list[dict]] = {}
    for row in rows:
        head, sep, _ = row["method"].rpartition(" (seed ")
        if sep:
            groups.setdefault(head, []).append(row)
    out = []
    for method, members in groups.items():
        if len(members) < 2:
            continue
        f1 = np.array([r["f1"] for r in members])
        width = np.array([r["width_bias_um"] for r in members])
        width = width[np.isfinite(width)]  # nan: a network that matched no cell
        out.append({
            "method": method,
            "seeds": len(members),
            "f1_mean": float(f1.mean()),
            "f1_sd": float(f1.std(ddof=1)),
            "width_bias_mean_um": float(width.mean()) if width.size else math.nan,
            "width_bias_sd_um": float(width.std(ddof=1)) if width.size > 1 else math.nan,
        })
    return out


def seed_means_table(rows: list[dict]) -> str:
    """Markdown table of :func:`seed_means`; empty when no method ran more than one seed."""
    means = seed_means(rows)
    if not means:
        return ""
    lines = [
        "| training data (mean over seeds) | seeds | F1@0.5 mean (s.d.) "
        "| width bias mean (s.d., um) |",
        "|---|---|---|---|",
    ]
    for m in means:
        lines.append(
            f"| {m['method']} | {m['seeds']} | {m['f1_mean']:.3f} ({m['f1_sd']:.3f}) | "
            f"{m['width_bias_mean_um']:+.3f} ({m['width_bias_sd_um']:.3f}) |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", choices=sorted(LOADERS), default="colicoords")
    parser.add_argument("--quick", action="store_true", help="tiny sizes (the test)")
    parser.add_argument("--steps", type=int, help="training steps per network")
    parser.add_argument("--n-synthetic", type=int, help="synthetic images per training set")
    parser.add_argument("--out", type=Path, help="folder for results JSON and pictures")
    parser.add_argument(
        "--seeds", type=int, nargs="+", default=[0, 1],
        help="seeds of the calibrated synthetic training sets and networks (default 0 1)",
    )
    parser.add_argument(
        "--baseline-seeds", type=int, nargs="+", default=[0],
        help="seeds of the real-annotation networks (default 0; one set of folds each)",
    )
    parser.add_argument(
        "--no-baselines",
        action="store_true",
        help="skip the real-annotation folds and the defaults row (they do not depend on "
        "calibrate: rerun only Otsu + watershed and the calibrated rows)",
    )
    parser.add_argument(
        "--packing",
        action="store_true",
        help="measure the Omnipose colonies' packing, real against calibrated synthetic, "
        "and stop (no training)",
    )
    args = parser.parse_args(argv)
    budget = QUICK if args.quick else Budget()
    if args.steps:
        budget = dataclasses.replace(budget, steps=args.steps)
    if args.n_synthetic:
        budget = dataclasses.replace(budget, n_synthetic=args.n_synthetic)
    import torch

    torch.set_num_threads(1)  # 2 threads on a loaded 2-core machine: 7x slower per step
    versions = ", ".join(f"{name} {version}" for name, version in package_versions().items())
    print(
        f"bench_transfer: {args.data}, {budget}; {versions}; on "
        f"{'cuda' if torch.cuda.is_available() else 'cpu'}; load average "
        f"{os.getloadavg()[0]:.1f}",
        flush=True,
    )
    start = time.perf_counter()
    if args.packing:
        rows = packing_rows(budget, n_images=2 if args.quick else 4)
        print(packing_table(rows))
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / "packing_omnipose.json").write_text(json.dumps(rows, indent=2))
        return rows
    rows = run(
        args.data,
        budget,
        args.out,
        seeds=tuple(args.seeds),
        baselines=not args.no_baselines,
        baseline_seeds=tuple(args.baseline_seeds),
    )
    print(table(rows))
    print(seed_means_table(rows))
    print(f"total {time.perf_counter() - start:.0f} s; load average {os.getloadavg()[0]:.1f}")
    return rows


if __name__ == "__main__":
    main()
