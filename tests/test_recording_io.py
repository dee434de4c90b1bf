"""Reading real recordings and their pixel size."""

from __future__ import annotations

import imageio.v3 as iio
import numpy as np
import pytest
import tifffile

from napari_symbac.io import axis_labels, napari_get_reader, read_image, read_recording
from napari_symbac.settings import Camera


def test_imagej_pixel_size(tmp_path):
    path = tmp_path / "stack.tif"
    data = np.arange(3 * 16 * 16, dtype=np.uint16).reshape(3, 16, 16)
    tifffile.imwrite(
        path, data, imagej=True, resolution=(1 / 0.08, 1 / 0.08), metadata={"unit": "um"}
    )
    recording = read_recording(path)
    assert recording.pixel_size_um == pytest.approx(0.08, rel=1e-4)
    assert recording.name == "stack"
    np.testing.assert_array_equal(recording.data, data)


def test_ome_pixel_size_in_nm(tmp_path):
    path = tmp_path / "field.ome.tif"
    tifffile.imwrite(
        path,
        np.zeros((16, 16), np.uint16),
        metadata={"PhysicalSizeX": 65.0, "PhysicalSizeXUnit": "nm"},
    )
    assert read_recording(path).pixel_size_um == pytest.approx(0.065)


@pytest.mark.parametrize(
    ("unit", "pixel_size_um"),
    [("\\u00B5m", 0.08), ("micron", 0.08), ("microns", 0.08), ("nm", 8e-5), ("inch", None)],
)
def test_imagej_units_as_files_spell_them(tmp_path, unit, pixel_size_um):
    """ImageJ's escaped micro sign, Micro-Manager's "micron(s)", nm; an inch (a scanner's
    default) is no microscope's pixel."""
    path = tmp_path / "spelt.tif"
    tifffile.imwrite(
        path,
        np.zeros((16, 16), np.uint16),
        imagej=True,
        resolution=(1 / 0.08, 1 / 0.08),
        metadata={"unit": unit},
    )
    read = read_recording(path).pixel_size_um
    assert read == (None if pixel_size_um is None else pytest.approx(pixel_size_um, rel=1e-4))


@pytest.mark.parametrize(
    ("unit", "pixel_size_um"), [("\u03bcm", 0.065), ("\u00b5m", 0.065), ("pixel", None)]
)
def test_ome_units_as_files_spell_them(tmp_path, unit, pixel_size_um):
    """The Greek mu (U+03BC) reads as the micro sign OME's schema names; a unit that is
    no length gives no pixel size (it was read as um)."""
    path = tmp_path / "spelt.ome.tif"
    tifffile.imwrite(
        path,
        np.zeros((16, 16), np.uint16),
        metadata={"PhysicalSizeX": 0.065, "PhysicalSizeXUnit": unit},
    )
    read = read_recording(path).pixel_size_um
    assert read == (None if pixel_size_um is None else pytest.approx(pixel_size_um))


def test_plain_tiff_has_no_pixel_size(tmp_path):
    path = tmp_path / "plain.tiff"
    tifffile.imwrite(path, np.zeros((16, 16), np.float32))
    assert read_recording(path).pixel_size_um is None


def test_reader_contract(tmp_path):
    path = tmp_path / "a.tif"
    tifffile.imwrite(
        path, np.ones((8, 8), np.uint16), imagej=True, resolution=(10, 10), metadata={"unit": "um"}
    )
    reader = napari_get_reader(str(path))
    ((_data, meta, kind),) = reader(str(path))
    assert kind == "image"
    assert meta["scale"] == pytest.approx((0.1, 0.1))
    assert meta["units"] == ("um", "um")  # napari's scale bar reads um, not "pixel"
    assert napari_get_reader(str(tmp_path / "a.png")) is None


def test_bad_files_are_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        read_recording(tmp_path / "nope.tif")
    broken = tmp_path / "broken.tif"
    broken.write_bytes(b"not a tiff at all")
    with pytest.raises(ValueError, match="not a readable TIFF"):
        read_recording(broken)
    text = tmp_path / "notes.txt"
    text.write_text("x")
    with pytest.raises(ValueError, match="is not a TIFF file"):
        read_recording(text)


def test_a_file_is_read_by_what_it_holds_not_only_by_its_name(tmp_path):
    """Found as a user: a TIFF saved without an extension was "not a TIFF or PNG file",
    and a PNG named .tif "not a readable TIFF ... convert it to TIFF". Their first bytes
    say what they are: both are read (read_image), and read_recording, a TIFF reader,
    names the PNG as one."""
    frame = np.arange(64, dtype=np.uint16).reshape(8, 8) + 100
    bare = tmp_path / "frame_without_extension"
    tifffile.imwrite(bare, frame, imagej=True, resolution=(10, 10), metadata={"unit": "um"})
    recording = read_image(bare)
    np.testing.assert_array_equal(recording.data, frame)
    assert recording.pixel_size_um == pytest.approx(0.1)
    png = tmp_path / "frame.tif"
    iio.imwrite(png, frame.astype(np.uint8), extension=".png")
    assert png.read_bytes()[:4] == b"\x89PNG"
    np.testing.assert_array_equal(read_image(png).data, frame.astype(np.uint8))
    with pytest.raises(ValueError, match=r"frame\.tif is a PNG file, not a TIFF: name it \.png"):
        read_recording(png)


@pytest.mark.parametrize(
    ("method", "modality"), [("Phase", "phase"), ("Fluorescence", "fluorescence")]
)
def test_ome_contrast_method_gives_modality(tmp_path, method, modality):
    path = tmp_path / "x.ome.tif"
    tifffile.imwrite(
        path,
        np.zeros((16, 16), np.uint16),
        metadata={"axes": "YX", "Channel": {"Name": "c", "ContrastMethod": method}},
    )
    assert read_recording(path).modality == modality
    assert read_recording(tmp_path / "x.ome.tif").pixel_size_um is None


@pytest.mark.parametrize(
    ("channel", "modality"),
    [
        ({"Name": "Ph3"}, "phase"),
        ({"Name": "mCherry-560"}, "fluorescence"),
        ({"Name": "c1", "Fluor": "GFP"}, "fluorescence"),
        ({"Name": "Trans"}, "brightfield"),
        ({"Name": "Brightfield", "ContrastMethod": "Phase"}, "phase"),  # its method rules
        ({"Name": "c1"}, None),
    ],
)
def test_an_ome_channels_name_gives_its_modality(tmp_path, channel, modality):
    path = tmp_path / "x.ome.tif"
    image = np.zeros((16, 16), np.uint16)
    tifffile.imwrite(path, image, metadata={"axes": "YX", "Channel": channel})
    assert read_recording(path).modality == modality


def test_read_image_takes_a_grey_png_and_grey_saved_as_colour(tmp_path):
    """The Omnipose sample colonies are grey PNGs saved as RGB(A): every command reads
    their grey channel, as the widgets do."""
    grey = (np.arange(40 * 48) % 251).astype(np.uint8).reshape(40, 48)
    iio.imwrite(tmp_path / "grey.png", grey)
    recording = read_image(tmp_path / "grey.png")
    np.testing.assert_array_equal(recording.data, grey)
    assert recording.pixel_size_um is None
    assert recording.name == "grey"
    rgba = np.dstack([grey, grey, grey, np.full_like(grey, 255)])
    iio.imwrite(tmp_path / "rgba.png", rgba)
    np.testing.assert_array_equal(read_image(tmp_path / "rgba.png").data, grey)
    deep = grey.astype(np.uint16) * 200
    iio.imwrite(tmp_path / "deep.png", deep)
    np.testing.assert_array_equal(read_image(tmp_path / "deep.png").data, deep)


def test_read_image_refuses_colour_and_other_formats_by_name(tmp_path):
    colour = np.zeros((16, 16, 3), np.uint8)
    colour[..., 0] = 200
    iio.imwrite(tmp_path / "colour.png", colour)
    with pytest.raises(ValueError, match=r"colour.png is a colour image"):
        read_image(tmp_path / "colour.png", "IMAGE")
    (tmp_path / "cells.jpg").write_bytes(b"x")
    with pytest.raises(ValueError, match=r"cells.jpg is not a TIFF or PNG"):
        read_image(tmp_path / "cells.jpg")
    with pytest.raises(ValueError, match=r"--masks .*nope.png does not exist"):
        read_image(tmp_path / "nope.png", "--masks")
    (tmp_path / "broken.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match=r"broken.png is not a readable PNG"):
        read_image(tmp_path / "broken.png")
    tiff = tmp_path / "stack.tif"
    tifffile.imwrite(tiff, np.ones((3, 8, 8), np.uint16))
    assert read_image(tiff).data.shape == (3, 8, 8)


def test_a_normalised_image_is_read_as_counts():
    from napari_symbac.io import NORMALISED_ADU_PER_UNIT, as_counts

    rng = np.random.default_rng(0)
    normalised = rng.normal(0.5, 0.1, (20, 20)).astype(np.float32)
    normalised[0, 0] = -0.02
    counts, mapping = as_counts(normalised)
    assert counts.min() == 0
    np.testing.assert_allclose(counts, (normalised + 0.02) * NORMALISED_ADU_PER_UNIT,
                               rtol=1e-6)  # fmt: skip
    assert mapping.shift == pytest.approx(0.02)
    assert mapping.adu_per_unit == NORMALISED_ADU_PER_UNIT
    assert (mapping.value_min, mapping.value_max) == (float(normalised.min()),
                                                      float(normalised.max()))  # fmt: skip
    assert mapping.formula == "(value + 0.02) x 10000 ADU"
    assert mapping.note.startswith("normalised values (-0.02..")
    assert f"read as {mapping.formula}, so that" in mapping.note
    # counts stored as floats, integers, wide ranges: as they are
    for image in (np.round(normalised * 1000), (normalised * 1000).astype(np.uint16),
                  normalised * 100, np.zeros((4, 4), np.uint8)):  # fmt: skip
        same, nothing = as_counts(image)
        assert same is image
        assert nothing is None


def test_an_unshifted_normalised_image_says_no_shift():
    """An image divided by its maximum (0..1, no negative values) is only scaled."""
    from napari_symbac.io import as_counts

    normalised = np.linspace(0.0, 1.0, 64, dtype=np.float32).reshape(8, 8)
    counts, mapping = as_counts(normalised)
    assert mapping.shift == 0.0
    assert mapping.formula == "(value) x 10000 ADU"
    np.testing.assert_allclose(mapping.values(counts), normalised, atol=1e-7)


@pytest.mark.parametrize("dtype", [np.float32, np.uint32, np.int64])
def test_an_image_beyond_16_bits_is_read_divided_into_them(dtype):
    """Found as a user: a sum projection (maximum 150140) was fitted with a 16-bit camera
    and its dataset clipped at 65535 over a fifth of its pixels, unsaid. It is divided
    by the smallest whole number that brings it within 50000 ADU, and said."""
    from napari_symbac.fit.preflight import check_fit_image
    from napari_symbac.io import as_counts

    image = (np.arange(64).reshape(8, 8) * 2383 + 20).astype(dtype)  # 20..150149
    counts, mapping = as_counts(image)
    assert mapping.adu_per_unit == pytest.approx(1 / 4)  # 150149 / 4 = 37537 <= 50000
    assert mapping.formula == "value / 4 ADU"
    assert mapping.note.startswith("values up to 150149, beyond the 16 bits (65535)")
    np.testing.assert_allclose(counts, image / 4.0)
    np.testing.assert_allclose(mapping.values(counts), image)
    check_fit_image(counts, "divided")  # what the fit takes
    with pytest.raises(ValueError, match="values up to 150149, beyond the 16 bits"):
        check_fit_image(image, "sum.tif")  # read without the map (napari's own reader)
    # a camera of the file's values, in the units read: baseline and gain divided too
    camera = mapping.camera(Camera(baseline_adu=400.0, sensitivity_adu_per_e=2.0))
    assert camera.baseline_adu == 100.0
    assert camera.sensitivity_adu_per_e == 0.5
    # within 16 bits, or with negative values (the fit refuses those as such): as it is
    assert as_counts(np.full((4, 4), 65535, dtype))[1] is None
    assert as_counts(image.astype(np.float64) - 1000)[1] is None


def test_the_delta_trench_read_as_counts_maps_back_to_its_values(real_data_dir):
    """The mapping a recording carries is data: its counts map back to the file's values."""
    path = real_data_dir / "ecoli_delta_phase_normalised.tiff"
    stored = tifffile.imread(path)
    recording = read_image(path, counts=True)
    mapping = recording.counts_mapping
    assert mapping.shift == pytest.approx(0.028468, abs=1e-6)
    assert mapping.formula == "(value + 0.02847) x 10000 ADU"
    assert recording.note == mapping.note
    np.testing.assert_allclose(mapping.values(recording.data), stored, atol=1e-6)
    np.testing.assert_allclose(mapping.counts_adu(stored), recording.data)
    # read as it is (masks, dark frames), the same file carries no mapping
    plain = read_image(path)
    assert plain.counts_mapping is None
    assert plain.note is None
    np.testing.assert_array_equal(plain.data, stored)


def test_the_reader_reads_a_normalised_image_as_counts(real_data_dir):
    """Found as a user: File -> Open with napari-symbac's reader kept DeLTA's normalised
    trench as floats, which Auto-fit then refused, while the dock's *or open* read it as
    counts."""
    path = real_data_dir / "ecoli_delta_phase_normalised.tiff"
    ((data, meta, kind),) = napari_get_reader(str(path))(str(path))
    assert kind == "image"
    assert data.min() == 0
    assert 10_000 < data.max() < 10_500
    mapping = meta["metadata"]["counts_mapping"]
    assert mapping.formula == "(value + 0.02847) x 10000 ADU"
    np.testing.assert_allclose(mapping.values(data), tifffile.imread(path), atol=1e-6)


@pytest.mark.parametrize(
    ("shape", "labels"),
    [((8, 9), ("y", "x")), ((3, 8, 9), ("frame", "y", "x"))],
)
@pytest.mark.parametrize("sized", [True, False])
def test_the_reader_names_the_axes(tmp_path, shape, labels, sized):
    """Found as a user: a time series opened with File -> Open showed its frame slider as
    "-3" (napari's default name), where the docks' layers read "frame"."""
    path = tmp_path / "a.tif"
    extra = {"imagej": True, "resolution": (10, 10), "metadata": {"unit": "um"}} if sized else {}
    tifffile.imwrite(path, np.ones(shape, np.uint16), **extra)
    ((_data, meta, _kind),) = napari_get_reader(str(path))(str(path))
    assert meta["axis_labels"] == labels
    assert len(meta["axis_labels"]) == len(meta.get("scale", shape))


def test_axis_labels_name_leading_axes_by_position():
    assert axis_labels(2) == ("y", "x")
    assert axis_labels(4) == ("axis 0", "frame", "y", "x")


def _hyperstack(path, axes: str, shape: tuple[int, ...], mode: str = "composite") -> np.ndarray:
    """An ImageJ hyperstack of ``axes`` (80 nm pixels) whose planes differ, shown in
    ``mode`` (Fiji shows channels as ``composite``)."""
    data = np.arange(int(np.prod(shape)), dtype=np.uint16).reshape(shape)
    tifffile.imwrite(
        path, data, imagej=True, resolution=(1 / 0.08, 1 / 0.08),
        metadata={"axes": axes, "unit": "um", "mode": mode},
    )  # fmt: skip
    return data


def test_a_channel_of_a_hyperstack_is_read_by_its_number(tmp_path):
    """Found as a user: a phase + fluorescence ImageJ hyperstack (axes CYX) was read as
    "2 frames", so `fit` asked for --frames and would have fitted the two channels as a
    time series. Its channel axis is now known: one channel is read, by number."""
    from napari_symbac.io import ChannelsError

    path = tmp_path / "two_channels.tif"
    data = _hyperstack(path, "TCYX", (3, 2, 16, 16))
    with pytest.raises(ChannelsError, match=r"holds 2 channels \(axes TCYX") as caught:
        read_recording(path)
    assert caught.value.n_channels == 2
    assert str(caught.value).endswith("a recording is one channel: pass channel=K (0..1)")
    second = read_recording(path, 1)
    np.testing.assert_array_equal(second.data, data[:, 1])
    assert second.pixel_size_um == pytest.approx(0.08, rel=1e-4)
    with pytest.raises(ValueError, match=r"channel 2: two_channels\.tif has channels 0\.\.1"):
        read_recording(path, 2)
    ome = tmp_path / "two_channels.ome.tif"  # Micro-Manager's and Bio-Formats' format
    tifffile.imwrite(ome, data, metadata={"axes": "TCYX"})
    with pytest.raises(ChannelsError, match="holds 2 channels"):
        read_recording(ome)
    np.testing.assert_array_equal(read_recording(ome, 0).data, data[:, 0])
    one = tmp_path / "one.tif"
    _hyperstack(one, "TYX", (3, 16, 16))
    assert read_recording(one, 0).data.shape == (3, 16, 16)
    with pytest.raises(ValueError, match="holds one channel"):
        read_recording(one, 1)


def test_a_colour_image_gives_the_channel_asked_for(tmp_path):
    """Found as a user: ``--channel 1`` of an RGB TIFF was refused ("holds one channel
    (axes YXS): leave the channel out"), and the refusal of a colour image without it
    did not name the flag."""
    rgb = np.random.default_rng(0).integers(0, 255, (32, 24, 3)).astype(np.uint8)
    tif, png = tmp_path / "rgb.tif", tmp_path / "rgb.png"
    tifffile.imwrite(tif, rgb, photometric="rgb")
    iio.imwrite(png, rgb)
    for path in (tif, png):
        np.testing.assert_array_equal(read_image(path, "IMAGE", channel=1).data, rgb[..., 1])
        with pytest.raises(ValueError, match="pick one with --channel K"):
            read_image(path, "IMAGE")
        with pytest.raises(ValueError, match=r"channel 3: .*colour image of channels 0\.\.2"):
            read_image(path, "IMAGE", channel=3)


def test_the_frame_interval_is_read_from_imagej_and_ome_metadata(tmp_path):
    """The time between frames a file records (ImageJ's finterval in its tunit, OME's
    TimeIncrement): a fit's settings draw the recording's frame interval from it."""
    stack = np.random.default_rng(0).integers(0, 1000, (3, 16, 16)).astype(np.uint16)
    paths = {name: tmp_path / f"{name}.tif" for name in ("sec", "min", "ome", "none")}
    tifffile.imwrite(paths["sec"], stack, imagej=True, metadata={"finterval": 30.0})
    tifffile.imwrite(paths["min"], stack, imagej=True,
                     metadata={"finterval": 2.0, "tunit": "min"})  # fmt: skip
    tifffile.imwrite(paths["ome"], stack, ome=True,
                     metadata={"axes": "TYX", "TimeIncrement": 90.0,
                               "TimeIncrementUnit": "s"})  # fmt: skip
    tifffile.imwrite(paths["none"], stack)
    intervals = {name: read_recording(path).frame_interval_s for name, path in paths.items()}
    assert intervals == {"sec": 30.0, "min": 120.0, "ome": 90.0, "none": None}


def test_a_grey_imagej_stack_is_frames_though_tifffile_calls_them_channels(tmp_path):
    """`tifffile.imwrite(path, series, imagej=True)`, axes unsaid, records a (T, Y, X)
    series as channels in grey mode: read as the frames it was written as (Fiji shows
    real channels as composite or colour)."""
    for axes, shape in (("CYX", (3, 16, 16)), ("TCYX", (2, 3, 16, 16))):
        path = tmp_path / f"{axes}.tif"
        data = _hyperstack(path, axes, shape, mode="grayscale")
        np.testing.assert_array_equal(read_recording(path).data, data)
    written = tmp_path / "written.tif"
    series = np.ones((3, 16, 16), np.uint16)
    tifffile.imwrite(written, series, imagej=True)
    assert tifffile.TiffFile(written).series[0].axes == "CYX"
    np.testing.assert_array_equal(read_recording(written).data, series)
    # ... but they may be channels (found as a user: a 2-channel ImageJ TIFF was read as
    # 2 frames without a word, and channel 1 was refused, "holds one channel"): said,
    # and a channel is read when asked for
    data_cyx = _hyperstack(tmp_path / "CYX.tif", "CYX", (3, 16, 16), mode="grayscale")
    recording = read_recording(tmp_path / "CYX.tif")
    assert "its 3 planes, ImageJ channels in grey mode" in recording.note
    assert "choose one (--channel K, K in 0..2)" in recording.note
    np.testing.assert_array_equal(read_recording(tmp_path / "CYX.tif", 1).data, data_cyx[1])
    assert read_recording(tmp_path / "CYX.tif", 1).note is None
    with pytest.raises(ValueError, match=r"channel 3: CYX\.tif has channels 0\.\.2"):
        read_recording(tmp_path / "CYX.tif", 3)


def test_focal_planes_beside_frames_are_refused_by_name(tmp_path):
    """A time-lapse of z-stacks: its focal planes are refused, not fitted as frames. An
    ImageJ stack that is no hyperstack (as Fiji saves a stack of images) names its pages
    slices (Z): they stay frames. A z-stack that OME metadata, an ImageJ hyperstack or
    tifffile's own record names so is refused too (found as a user: an OME z-stack was
    read as a time-lapse, which Auto-fit would track through focus)."""
    path = tmp_path / "zstacks.tif"
    _hyperstack(path, "TZCYX", (3, 5, 2, 16, 16))
    with pytest.raises(ValueError, match=r"holds 5 focal planes \(axes TZCYX") as caught:
        read_recording(path, 0)
    assert "Make Substack" in str(caught.value)
    plain = tmp_path / "plain_stack.tif"
    data = np.arange(5 * 16 * 16, dtype=np.uint16).reshape(5, 16, 16)
    tifffile.imwrite(
        plain, data, description="ImageJ=1.54f\nimages=5\nslices=5\nunit=micron\n",
        metadata=None, resolution=(1 / 0.08, 1 / 0.08),
    )  # fmt: skip
    recording = read_recording(plain)
    np.testing.assert_array_equal(recording.data, data)
    assert recording.pixel_size_um == pytest.approx(0.08, rel=1e-4)
    ome, hyperstack, shaped = (tmp_path / f"{kind}_z.tif" for kind in ("ome", "ij", "shaped"))
    tifffile.imwrite(ome, data, ome=True, metadata={"axes": "ZYX"})
    _hyperstack(hyperstack, "ZYX", (5, 16, 16))
    tifffile.imwrite(shaped, data, metadata={"axes": "ZYX"})
    for path in (ome, hyperstack, shaped):
        with pytest.raises(ValueError, match=r"holds 5 focal planes \(axes ZYX"):
            read_recording(path)
        with pytest.raises(ValueError, match="focal planes"):
            napari_get_reader(str(path))(str(path))


def test_the_reader_opens_a_layer_per_channel(tmp_path):
    """napari's way with channels: one layer each, in micrometres, so that the channel to
    fit is chosen as a layer."""
    path = tmp_path / "two_channels.tif"
    data = _hyperstack(path, "CYX", (2, 16, 16))
    layers = napari_get_reader(str(path))(str(path))
    assert [meta["name"] for _, meta, _ in layers] == [
        "two_channels channel 0", "two_channels channel 1"
    ]  # fmt: skip
    for k, (array, meta, kind) in enumerate(layers):
        assert kind == "image"
        np.testing.assert_array_equal(array, data[k])
        assert meta["scale"] == pytest.approx((0.08, 0.08), rel=1e-4)


def test_the_reader_names_channel_layers_as_the_ome_file_does(tmp_path):
    """Found as a user: an OME-TIFF of channels BF and GFP opened as "channel 0" and
    "channel 1", leaving the user to guess which was which."""
    data = np.arange(2 * 16 * 16, dtype=np.uint16).reshape(2, 16, 16)
    named, unnamed = tmp_path / "named.ome.tif", tmp_path / "unnamed.ome.tif"
    tifffile.imwrite(named, data, ome=True,
                     metadata={"axes": "CYX", "Channel": {"Name": ["BF", "GFP"]}})  # fmt: skip
    tifffile.imwrite(unnamed, data, ome=True, metadata={"axes": "CYX"})
    layers = napari_get_reader(str(named))(str(named))
    assert [meta["name"] for _, meta, _ in layers] == ["named.ome BF", "named.ome GFP"]
    np.testing.assert_array_equal(layers[1][0], data[1])
    # and their modalities (found as a user: the BF channel was guessed phase)
    modalities = [meta["metadata"]["modality"] for _, meta, _ in layers]
    assert modalities == ["brightfield", "fluorescence"]
    assert [read_recording(named, channel=k).modality for k in (0, 1)] == modalities
    layers = napari_get_reader(str(unnamed))(str(unnamed))
    assert [meta["name"] for _, meta, _ in layers] == [
        "unnamed.ome channel 0", "unnamed.ome channel 1"
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("shapes", "advice"),
    [
        (((200, 200), (180, 220)), "save each image as its own TIFF"),
        (((20, 20), (20, 20)), "save them as one stack"),
    ],
)
def test_a_tiff_of_several_separate_images_is_refused(tmp_path, shapes, advice):
    """Found as a user: a TIFF of pages of 200 x 200 and 180 x 220 px was read as its
    first page, and `fit --frames 0-1` said it had 1 frame. Images written one after
    another are tifffile's separate series: refused, not cut to the first."""
    path = tmp_path / "pages.tif"
    with tifffile.TiffWriter(path) as tif:
        for k, shape in enumerate(shapes):
            tif.write(np.full(shape, 5 + k, np.uint16))
    with pytest.raises(ValueError, match="holds 2 separate images") as refused:
        read_recording(path)
    assert advice in str(refused.value)
    assert str(path) in str(refused.value)
    tifffile.imwrite(tmp_path / "stack.tif", np.zeros((2, 20, 20), np.uint16))
    assert read_recording(tmp_path / "stack.tif").data.shape == (2, 20, 20)
