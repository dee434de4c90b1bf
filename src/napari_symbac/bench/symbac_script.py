"""The script run by SyMBac 0.5.2's interpreter (a subprocess; SyMBac is never imported here).

It reads a JSON object of settings from ``argv[1]``, runs one SyMBac trench simulation,
times it, its per-frame render path and its training-data export on that simulation,
and prints one JSON object of numbers (seconds per unit, peak MiB) as its last line.
"""

#: SyMBac's Ph3 phase-contrast PSF and a ``Renderer`` of ``sim`` matched against a
#: camera-sized noise image ``real``, its canvas cut to ``shape`` (napari-symbac's render
#: frame). Needs ``sim``, ``shape`` and ``camera_shape``; indented for the block that
#: silences SyMBac. Shared by :data:`SCRIPT` and ``benchmarks/compare_trench_frame.py``,
#: so that both time SyMBac at the same settings.
RENDERER_SETUP = r"""
    psf = PSF_generator(radius=50, wavelength=0.65, NA=1.45, n=1.518, resize_amount=3,
                        pix_mic_conv=0.065, apo_sigma=10, mode="phase contrast", condenser="Ph3")
    psf.calculate_PSF()
    real = np.random.default_rng(0).normal(1000, 50, camera_shape).clip(0)
    renderer = Renderer(sim, psf, real)
    regions = renderer.auto_segment_regions()
    means = [renderer.real_resize[regions[k]].mean() for k in ("media", "cell", "device")]
    var = [renderer.real_resize[regions[k]].var() for k in ("media", "cell", "device")]
    renderer.image_params = (*means, np.mean(means), *var, np.mean(var))
    expanded, _, _ = renderer.generate_PC_OPL(
        sim.OPL_scenes[-1], sim.masks[-1], 75, 1.7, 29,
        renderer.y_border_expansion_coefficient, renderer.x_border_expansion_coefficient, 3.0)
    base = np.array(expanded.shape) / np.array(
        [renderer.y_border_expansion_coefficient, renderer.x_border_expansion_coefficient])
    renderer.y_border_expansion_coefficient = (shape[0] + 0.5) / base[0]
    renderer.x_border_expansion_coefficient = (shape[1] + 0.5) / base[1]
"""

SCRIPT = r"""
import contextlib, io, json, resource, sys, tempfile, time, types, warnings
warnings.filterwarnings("ignore")
import numpy as np
cfg = json.loads(sys.argv[1])
quiet_out, quiet_err = io.StringIO(), io.StringIO()
with contextlib.redirect_stdout(quiet_out), contextlib.redirect_stderr(quiet_err):
    from SyMBac.PSF import PSF_generator, Camera
    from SyMBac.drawing import draw_scene_from_segments
    from SyMBac.renderer import Renderer
    from SyMBac.simulation import Simulation

result = {}
frames = cfg["sim_frames"]
# the trench of napari-symbac's rows: 15 um x 1.4 um, 0.065 um/px, resize 3; SyMBac takes
# standard deviations (sqrt(0.04) = 0.2 um, sqrt(0.0025) = 0.05 um)
with contextlib.redirect_stdout(quiet_out), contextlib.redirect_stderr(quiet_err):
    sim = Simulation(trench_length=15, trench_width=1.4, cell_max_length=3.5, max_length_std=0.2,
                     cell_width=1.0, width_std=0.05, lysis_p=0.0, sim_length=frames,
                     pix_mic_conv=0.065, gravity=0, phys_iters=15, resize_amount=3,
                     save_dir=tempfile.mkdtemp())
    t0 = time.perf_counter()
    sim.run_simulation(show_window=False)
    result["sim_s_per_frame"] = (time.perf_counter() - t0) / frames
    t0 = time.perf_counter()
    sim.draw_simulation_OPL(do_transformation=False, label_masks=True)
    result["draw_opl_s"] = time.perf_counter() - t0

    # per-frame path: draw_scene_from_segments + generate_test_comparison (OPL, PSF,
    # defocus, convolve + rescale, histogram matching, noise, masks), canvas cut to
    # napari-symbac's render frame
    shape = tuple(cfg["render_shape"])
    camera_shape = tuple(cfg["camera_shape"])
""" + RENDERER_SETUP + r"""

    def full_path(k):
        draw_scene_from_segments(
            sim.cell_timeseries_segments[k], sim._space_size, sim.offset, sim._label_masks)
        renderer.generate_test_comparison(scene_no=k)

    n_render = min(cfg["render_frames"], len(sim.OPL_scenes) - 1)
    ks = list(range(len(sim.OPL_scenes) - n_render, len(sim.OPL_scenes)))
    full_path(ks[0])
    times = []
    for k in ks:
        t0 = time.perf_counter()
        full_path(k)
        times.append(time.perf_counter() - t0)
    result["render_s_per_frame"] = float(np.median(times))

    # training-data export: image/mask pairs of random frames, intensities set directly
    # (no matching), as napari-symbac's export of the same trench
    camera = Camera(baseline=100, sensitivity=2.9, dark_noise=8)
    exporter = Renderer(simulation=sim, PSF=psf, real_image=real.astype(np.uint16), camera=camera)
    m, v = real.mean(), real.var()
    exporter.image_params = (m, m * 0.6, m * 0.4, np.array((m, 0.6 * m, 0.4 * m)),
                             v, v, v, np.array((v, v, v)))
    exporter.params = types.SimpleNamespace(kwargs=dict(
        media_multiplier=75, cell_multiplier=1.7, device_multiplier=29,
        sigma=psf.min_sigma * 2, match_histogram=False, match_noise=False,
        match_fourier=False, noise_var=0.001, defocus=0, halo_top_intensity=0,
        halo_bottom_intensity=0, halo_start=0, halo_end=0, cell_texture_strength=0,
        cell_texture_scale=70, edge_floor_opl=0.0))
    n = cfg["export_n"]
    t0 = time.perf_counter()
    exporter.generate_training_data(
        sample_amount=0.1, randomise_hist_match=False, randomise_noise_match=False,
        burn_in=min(20, frames // 3), n_samples=n, save_dir=tempfile.mkdtemp(),
        in_series=False)
    render_s = time.perf_counter() - t0
    result["export_s_per_image"] = render_s / n
    # overall: as napari-symbac's export, which simulates export_sim_frames frames first
    per_frame = result["sim_s_per_frame"] + result["draw_opl_s"] / frames
    result["export_overall_s_per_image"] = (
        render_s + per_frame * cfg["export_sim_frames"]) / n
# VmHWM: ru_maxrss would be inherited from the (large) process this one was forked from
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
try:
    with open("/proc/self/status") as status:
        peak = next(int(l.split()[1]) / 1024 for l in status if l.startswith("VmHWM:"))
except (OSError, StopIteration):
    pass
result["peak_mib"] = peak
print(json.dumps(result))
"""
