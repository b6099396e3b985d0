"""A gantry's control software as another lab would write it: numpy, tifffile and the stdlib.

This file deliberately knows nothing of spectralize (it imports none of it): it follows only
the documented capture-folder format (``datasets/README.md``, "Capture folders"), with its own
physics, its own camera names, bit depths, frame size, file layout and calibration sampling,
so that an ingest of its output tests the format and not the simulator that wrote the format's
sample.

What it models (all of it different from spectralize's simulator on purpose):

- a rectified 40 x 52 px sample of six smooth reflectances in stripes, checks and a dark
  corner, over a bumpy surface (shading changes with the light per texel);
- a white LED with a sharp blue peak at 452 nm, given at 2 nm steps 380-780 nm;
- two 12-bit RGB cameras (10 and 45 degree) with Gaussian sensitivities and a compressive
  response ``DN = 16 + 4079 * y ** 0.82``, exposure series with ratios 2 and 3 in turn;
- a 12-bit monochrome camera behind a tunable filter at 45 degree, 15 degree in azimuth beside
  the 45 degree RGB camera, misregistered by (0.4, -0.7) px; dark offset with fixed pattern
  and hot pixels, dark current, 2.5 DN read noise, shot noise, a slightly compressive response;
- band shots spread over five LED positions (a sweep of 32 bands, 410-720 nm), exposure
  times from eq. 2 with its own ``t0``, ``omega``;
- an 18-patch chart of its own (``colour_checker.csv``), photographed (with the white
  reference) by every RGB camera, each framing it a little differently: a patch label image
  per camera as TIFF (``colour_checker.patch_indices``), the sensor model of each camera in
  ``rgb.models`` and, where the LEDs' powers differ, the lab's measurement of them
  (``calibration/led_power.csv``, 0.3 % repeatability);
- every file TIFF (some zlib-compressed), in nested folders; manifest columns in another
  order, with extra columns;
- optionally (``falloff`` in the lab) a lens falloff on every frame the lab writes (scene,
  targets, white reference, registration): ``cos^4``-type, 1 on the axis (the frame centre),
  ``rgb`` less light in the corners for the RGB cameras, and for the spectral camera
  ``spectral`` at the band range's middle, ``spectral_slope`` more at its red end and less at
  its blue end (the tunable filter's off-axis loss).

What the gantry is made of (illuminant, materials, chart, RGB cameras and their sensor
models: sensitivity, response, black offset and optionally a white level, the code its values
clip at, below the top code; LED power) is one dictionary, :func:`default_lab`;
``foreign_gantry_models.py`` writes harder labs through the same code.

Usage: ``python foreign_gantry.py OUT [--truth truth.npz]``. Deterministic (fixed seed).
``--truth`` writes what a lab never has (material map, reflectances, illuminant, every RGB
camera's sensitivity and model, LED power) beside, not inside, the capture folder, so that a
test can judge the calibration and the reconstruction.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import tifffile

HEIGHT, WIDTH = 40, 52
WAVELENGTHS = np.arange(410.0, 721.0, 10.0)  # the tunable filter's 32 bands [nm]
ROTATION_STEP = 15.0  # [degree]; the spectral camera sits this far in azimuth from cam-45
MISREGISTRATION = (0.4, -0.7)  # spectral camera content shift (dy, dx) [px]
RGB_MAX = MONO_MAX = 4095  # 12-bit cameras
SESSION = "session_2026-11-20"
PAIRED = "cam-45"
MONO = "vis-mono"
LED_THETA = 35.0
LED_AZIMUTHS = [150.0 + 15.0 * k for k in range(6)]  # LED 100 + k
T0, S0, OMEGA = 0.03, 0.25, 0.8  # eq. 2 and 3 constants of this lab's exposure plan
RGB_TIMES = [0.002, 0.004, 0.012, 0.024, 0.072]  # ratios 2, 3, 2, 3 [s]
CHART_OFFSET = {"cam-top": (1, -2), "cam-45": (0, 0), "cam-side": (-1, 1)}  # chart framing [px]
LAB: dict = {}  # what this lab's gantry is made of (:func:`default_lab`), set by write_capture


def series(first: float, count: int) -> list[float]:
    """Exposure times with ratios 2 and 3 in turn (a geometric bracket leaves Robertson's
    response undetermined up to a periodic factor)."""
    times = [first]
    for k in range(count - 1):
        times.append(round(times[-1] * (2 if k % 2 == 0 else 3), 10))
    return times


def gauss(wl: np.ndarray, centre: float, width: float) -> np.ndarray:
    return np.exp(-0.5 * ((wl - centre) / width) ** 2)


def phosphor_led(wl: np.ndarray) -> np.ndarray:
    """A phosphor-white LED: narrow blue peak plus broad phosphor band (relative)."""
    return 0.95 * gauss(wl, 452.0, 10.0) + 0.7 * gauss(wl, 565.0, 55.0) + 0.03


def illuminant(wl: np.ndarray) -> np.ndarray:
    """The lab's LED (relative)."""
    return LAB["illuminant"](wl)


def rgb_sensitivity(wl: np.ndarray, camera: str = "cam-45") -> np.ndarray:
    """(3, wavelength) R, G, B sensitivities (relative) of an RGB camera's model."""
    return LAB["models"][LAB["rgb_cameras"][camera][2]]["sensitivity"](wl)


def gaussian_sensitivity(wl: np.ndarray) -> np.ndarray:
    """(3, wavelength) this lab's first camera model: Gaussian lobes (relative)."""
    return np.stack(
        [
            gauss(wl, 602.0, 36.0) + 0.06 * gauss(wl, 445.0, 18.0),
            gauss(wl, 535.0, 38.0),
            gauss(wl, 458.0, 27.0),
        ]
    )


def mono_efficiency(wl: np.ndarray) -> np.ndarray:
    """Quantum efficiency times filter transmission of the spectral camera (weak in the blue)."""
    return 0.12 + 0.6 * gauss(wl, 630.0, 110.0)


def sigmoid(wl: np.ndarray, edge: float, width: float) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-(wl - edge) / width))


def material_reflectances(wl: np.ndarray) -> np.ndarray:
    """(6, wavelength) reflectances of the sample's six materials."""
    return LAB["materials"](wl)


def chart_reflectances(wl: np.ndarray) -> np.ndarray:
    """(patch, wavelength) reflectances of the lab's chart."""
    return LAB["chart"](wl)


def smooth_materials(wl: np.ndarray) -> np.ndarray:
    """(6, wavelength) reflectances: red, green, blue, yellow, grey, brown."""
    return np.stack(
        [
            0.05 + 0.7 * sigmoid(wl, 595.0, 12.0),
            0.06 + 0.45 * gauss(wl, 530.0, 35.0),
            0.08 + 0.5 * gauss(wl, 460.0, 30.0) + 0.1 * sigmoid(wl, 690.0, 10.0),
            0.07 + 0.75 * sigmoid(wl, 520.0, 15.0),
            0.35 + 0.05 * (wl - 560.0) / 160.0,
            0.04 + 0.25 * sigmoid(wl, 620.0, 40.0) + 0.05 * gauss(wl, 560.0, 30.0),
        ]
    )


def smooth_chart(wl: np.ndarray) -> np.ndarray:
    """(18, wavelength) this lab's own chart: varied smooth spectra and greys."""
    rng = np.random.default_rng(1234)
    patches = []
    for _ in range(14):
        centre, width = rng.uniform(420.0, 700.0), rng.uniform(25.0, 80.0)
        edge = rng.uniform(450.0, 680.0)
        patches.append(
            0.04
            + rng.uniform(0.2, 0.6) * gauss(wl, centre, width)
            + rng.uniform(0.0, 0.5) * sigmoid(wl, edge, rng.uniform(8.0, 30.0))
        )
    patches += [np.full(wl.shape, v) for v in (0.9, 0.55, 0.2, 0.04)]
    return np.clip(np.stack(patches), 0.01, 0.95)


# -- the sample, evaluated at continuous positions (pixels integrate over their area) -----
def material_at(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Material index at rectified sample position (y, x) [px]."""
    stripes = np.floor(x / 3.0).astype(int) % 3  # red, green, blue stripes 3 px wide
    checks = 3 + (np.floor(y / 4.0) + np.floor(x / 4.0)).astype(int) % 2  # yellow / grey checks
    out = np.where(y < HEIGHT / 2, stripes, checks)
    dark = (y > HEIGHT * 0.7) & (x > WIDTH * 0.6)
    return np.where(dark, 5, out)


def height_at(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Surface height [px]: smooth bumps, so each texel's shading changes with the light."""
    return 1.6 * np.sin(y / 3.1) * np.cos(x / 4.3) + 0.8 * np.sin((x + y) / 2.3)


def supersampled(y0: float, x0: float, factor: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Sample positions (factor^2 per pixel) of the frame's pixels, content shifted by (y0, x0)."""
    offsets = (np.arange(factor) + 0.5) / factor - 0.5
    yy = np.arange(HEIGHT)[:, None, None, None] + offsets[None, None, :, None] - y0
    xx = np.arange(WIDTH)[None, :, None, None] + offsets[None, None, None, :] - x0
    return np.broadcast_arrays(yy, xx)


def direction(theta: float, phi: float) -> np.ndarray:
    t, p = np.deg2rad(theta), np.deg2rad(phi)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def radiance(theta_i: float | None, phi_i: float, shift=(0.0, 0.0)) -> np.ndarray:
    """(wavelength, y, x) radiance (relative) of the sample under one LED (None: diffuse dome)."""
    yy, xx = supersampled(*shift)
    materials = material_at(yy, xx)
    if theta_i is None:
        shade = np.full(yy.shape, 0.8)
    else:
        eps = 0.05
        gy = (height_at(yy + eps, xx) - height_at(yy - eps, xx)) / (2 * eps)
        gx = (height_at(yy, xx + eps) - height_at(yy, xx - eps)) / (2 * eps)
        normal = np.stack([-gx * 0.35, -gy * 0.35, np.ones_like(gx)], axis=-1)
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        shade = np.clip(normal @ direction(theta_i, phi_i), 0.02, None)
    reflect = material_reflectances(WAVELENGTHS)[materials]  # (y, x, s, s, wavelength)
    value = reflect * shade[..., None] * illuminant(WAVELENGTHS)
    return np.moveaxis(value.mean(axis=(2, 3)), -1, 0)


# -- cameras --------------------------------------------------------------------------------
RGB_SCALE = 150.0  # y = RGB_SCALE * t * (S . L) ; DN = 16 + 4079 * y ** 0.82
MONO_GAIN = 1100.0  # DN per second per unit of Q * L


def power_oecf(y: np.ndarray) -> np.ndarray:
    """The first model's compressive response: 0..1 over 0..1 exposure, rising beyond."""
    return y**0.82


def lens_falloff(corner_loss: float) -> np.ndarray:
    """(y, x) a ``cos^4``-type falloff ``1 / (1 + a r^2)^2``: 1 on the axis (the frame centre),
    ``1 - corner_loss`` in the corners."""
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH] + 0.5
    r2 = ((yy - HEIGHT / 2) ** 2 + (xx - WIDTH / 2) ** 2) / ((HEIGHT / 2) ** 2 + (WIDTH / 2) ** 2)
    return 1.0 / (1.0 + ((1.0 - corner_loss) ** -0.5 - 1.0) * r2) ** 2


def rgb_falloff() -> np.ndarray:
    """(y, x) the RGB cameras' lens falloff (ones without ``falloff`` in the lab)."""
    falloff = LAB.get("falloff")
    return lens_falloff(falloff["rgb"]) if falloff else np.ones((HEIGHT, WIDTH))


def mono_falloff(wavelength: float) -> np.ndarray:
    """(y, x) the spectral camera's falloff at ``wavelength`` (lens and filter)."""
    falloff = LAB.get("falloff")
    if not falloff:
        return np.ones((HEIGHT, WIDTH))
    middle, half = WAVELENGTHS.mean(), (WAVELENGTHS.max() - WAVELENGTHS.min()) / 2
    loss = falloff["spectral"] + falloff["spectral_slope"] * (wavelength - middle) / half
    return lens_falloff(loss)


def rgb_counts(rng, rad: np.ndarray, t: float, camera: str = "cam-45") -> np.ndarray:
    model = LAB["models"][LAB["rgb_cameras"][camera][2]]
    signal = np.einsum("cw,wyx->yxc", model["sensitivity"](WAVELENGTHS), rad) / WAVELENGTHS.size
    signal = signal * rgb_falloff()[..., None]
    y = RGB_SCALE * t * signal
    y = y + rng.normal(0.0, 1.0, y.shape) * np.sqrt(y / 5000.0 + 1e-7)
    black = model["black"]
    response = model["oecf"](np.clip(y, 0.0, None))  # 1 at full scale, above it saturated
    dn = black + (RGB_MAX - black) * response + rng.normal(0.0, 1.2, y.shape)
    white = model.get("white", RGB_MAX)  # a white level under the top code clips there
    return np.clip(np.round(dn), 0, white).astype(np.uint16)


def dark_pattern() -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel dark offset [DN] and dark current [DN/s] (fixed pattern, a few hot pixels)."""
    rng = np.random.default_rng(77)
    offset = 48.0 + rng.normal(0.0, 1.5, (HEIGHT, WIDTH))
    current = rng.gamma(4.0, 0.6, (HEIGHT, WIDTH))
    hot = rng.random((HEIGHT, WIDTH)) < 0.004
    current[hot] *= 25.0
    return offset, current


def mono_counts(rng, band_radiance: np.ndarray | None, wavelength: float | None, t: float) -> np.ndarray:
    """One frame of the spectral camera; ``band_radiance`` None: shutter closed (dark frame)."""
    offset, current = dark_pattern()
    electrons = current * t
    if band_radiance is not None:
        q = float(mono_efficiency(np.array([wavelength]))[0])
        electrons = electrons + MONO_GAIN * t * q * band_radiance * mono_falloff(wavelength)
    electrons = electrons + rng.normal(0.0, 1.0, electrons.shape) * np.sqrt(electrons / 4.0)
    response = electrons * (1.0 - 0.06 * np.clip(electrons, 0, None) / MONO_MAX)
    dn = offset + response + rng.normal(0.0, 2.5, electrons.shape)
    return np.clip(np.round(dn), 0, MONO_MAX).astype(np.uint16)


def band_exposure_times() -> np.ndarray:
    """Eq. 2 of this lab: t_i = t0 * (relative band signal) ** -omega, in ms steps."""
    relative = mono_efficiency(WAVELENGTHS) * illuminant(WAVELENGTHS)
    relative = relative / relative.max()
    return np.round(T0 * relative**-OMEGA, 4)


# -- writing --------------------------------------------------------------------------------
def save(root: Path, name: str, image: np.ndarray, compress: bool = False) -> str:
    path = root / name
    path.parent.mkdir(parents=True, exist_ok=True)
    photometric = "rgb" if image.ndim == 3 else "minisblack"
    tifffile.imwrite(
        path, image, photometric=photometric, compression="zlib" if compress else None, metadata=None
    )
    return name


COLUMNS = [  # this lab's order, with extra columns the format ignores
    "file",
    "camera",
    "kind",
    "exposure_time_s",
    "wavelength_nm",
    "rotation",
    "led",
    "theta_o",
    "phi_o",
    "theta_i",
    "phi_i",
    "timestamp",
    "operator",
]


def sample_frame_angles(camera_azimuth: float, theta_o: float, led: int, rotation: int) -> dict:
    """Light and view direction in the sample's frame (the stage turned by rotation * step)."""
    turn = rotation * ROTATION_STEP
    return {
        "theta_i": LED_THETA,
        "phi_i": (LED_AZIMUTHS[led - 100] - turn) % 360.0,
        "theta_o": theta_o,
        "phi_o": (camera_azimuth - turn) % 360.0,
    }


def default_lab() -> dict:
    """This lab's gantry: two RGB cameras of one model (Gaussian sensitivities, a compressive
    response, black 16 DN), the phosphor LED, six smooth materials and an 18-patch chart."""
    return {
        "name": "bumpy stripes, night of 2026-11-20",
        "illuminant": phosphor_led,
        "materials": smooth_materials,
        "chart": smooth_chart,
        "rgb_cameras": {"cam-top": (10.0, 0.0, "gauss"), "cam-45": (45.0, 0.0, "gauss")},
        "models": {"gauss": {"sensitivity": gaussian_sensitivity, "black": 16.0, "oecf": power_oecf}},
        "led_power": {},  # LED number: relative power (1 when absent)
    }


def write_capture(root: Path, truth: Path | None = None, lab: dict | None = None) -> Path:
    """Write the capture folder (and the truth beside it); ``lab`` (default
    :func:`default_lab`) says what the gantry is made of."""
    LAB.clear()
    LAB.update(lab or default_lab())
    cameras = LAB["rgb_cameras"]
    power = LAB["led_power"]
    rng = np.random.default_rng(20261120)
    root.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    clock = [0]

    def add(**row):
        clock[0] += 1
        rows.append(
            row
            | {
                "timestamp": f"2026-11-20T22:{clock[0] // 60 % 60:02d}:{clock[0] % 60:02d}",
                "operator": "night shift",
            }
        )

    # RGB images: 2 rotations x 6 LEDs x 2 cameras, an exposure series each
    for rotation in (0, 1):
        for led in range(100, 106):
            for camera, (theta_o, azimuth, _) in cameras.items():
                angles = sample_frame_angles(azimuth, theta_o, led, rotation)
                rad = power.get(led, 1.0) * radiance(angles["theta_i"], angles["phi_i"])
                for e, t in enumerate(RGB_TIMES):
                    name = save(
                        root,
                        f"{SESSION}/rgb/{camera}/r{rotation}_led{led}_e{e}.tif",
                        rgb_counts(rng, rad, t, camera),
                        compress=e % 2 == 0,
                    )
                    add(
                        file=name,
                        camera=camera,
                        kind="rgb",
                        exposure_time_s=t,
                        rotation=rotation,
                        led=led,
                        **angles,
                    )

    # band shots: the spectral camera at rotation 1 sees what cam-45 saw at rotation 0 with
    # the LED one step (15 degree) before; 32 bands spread over LEDs 101..105
    times = band_exposure_times()
    spectral_azimuth = cameras[PAIRED][1] + ROTATION_STEP
    for k, led in enumerate(range(101, 106)):
        angles = sample_frame_angles(spectral_azimuth, 45.0, led, rotation=1)
        rad = power.get(led, 1.0) * radiance(angles["theta_i"], angles["phi_i"], shift=MISREGISTRATION)
        for b in range(k, WAVELENGTHS.size, 5):
            wl = float(WAVELENGTHS[b])
            name = save(
                root,
                f"{SESSION}/bands/led{led}/{int(wl)}nm.tif",
                mono_counts(rng, rad[b], wl, float(times[b])),
            )
            add(
                file=name,
                camera=MONO,
                kind="spectral",
                exposure_time_s=float(times[b]),
                wavelength_nm=wl,
                rotation=1,
                led=led,
                **angles,
            )

    # calibration targets under one LED at normal incidence, camera at 45 degree
    wl_white = np.full(WAVELENGTHS.shape, 0.97)
    chart = chart_reflectances(WAVELENGTHS)
    patches = np.zeros((HEIGHT, WIDTH), np.uint16)  # 0 frame, k patch k (cam-45 pixels)
    cols_of = 6
    rows_of = -(-chart.shape[0] // cols_of)
    ph, pw = HEIGHT // rows_of, WIDTH // cols_of
    for p in range(chart.shape[0]):
        r, c = divmod(p, cols_of)
        patches[r * ph + 1 : (r + 1) * ph - 1, c * pw + 1 : (c + 1) * pw - 1] = p + 1
    light = illuminant(WAVELENGTHS)

    def target(reflectance_map: np.ndarray, shift=(0.0, 0.0)) -> np.ndarray:
        """(wavelength, y, x) radiance of a flat target (pixel-integrated, shifted content)."""
        yy, xx = supersampled(*shift)
        y = np.clip(np.floor(yy).astype(int), 0, HEIGHT - 1)
        x = np.clip(np.floor(xx).astype(int), 0, WIDTH - 1)
        return np.moveaxis(reflectance_map[y, x].mean(axis=(2, 3)), -1, 0) * light[:, None, None]

    white_map = np.broadcast_to(wl_white, (HEIGHT, WIDTH, WAVELENGTHS.size))
    chart_map = np.concatenate([np.full((1, WAVELENGTHS.size), 0.02), chart])[patches]
    spectral_series = series(0.001, 13)
    for kind, reflectance_map in (("white_reference", white_map), ("colour_checker", chart_map)):
        # every RGB camera photographs the targets; each frames the chart a little differently
        for camera in cameras:
            view = np.roll(reflectance_map, CHART_OFFSET[camera], axis=(0, 1))
            seen_rgb = target(view)
            folder = "" if camera == PAIRED else f"{camera}/"
            for e, t in enumerate(series(0.0002, 9)):
                name = save(
                    root,
                    f"{SESSION}/calibration_shots/{kind}/{folder}rgb_{e:02d}.tif",
                    rgb_counts(rng, seen_rgb, t, camera),
                )
                add(file=name, camera=camera, kind=kind, exposure_time_s=t)
        seen_mono = target(reflectance_map, shift=MISREGISTRATION)
        for b, wl in enumerate(WAVELENGTHS):
            for e, t in enumerate(spectral_series):
                name = save(
                    root,
                    f"{SESSION}/calibration_shots/{kind}/{int(wl)}nm_{e:02d}.tif",
                    mono_counts(rng, seen_mono[b], float(wl), t),
                    compress=True,
                )
                add(file=name, camera=MONO, kind=kind, exposure_time_s=t, wavelength_nm=float(wl))

    # registration: a long exposure per rotation and camera under the diffuse dome
    for rotation in (0, 1):
        name = save(
            root,
            f"{SESSION}/registration/cam-45_r{rotation}.tif",
            rgb_counts(rng, radiance(None, 0.0), 0.01),
        )
        add(file=name, camera=PAIRED, kind="registration", exposure_time_s=0.01, rotation=rotation)
        band = int(np.flatnonzero(WAVELENGTHS == 600.0)[0])
        name = save(
            root,
            f"{SESSION}/registration/mono_r{rotation}.tif",
            mono_counts(rng, radiance(None, 0.0, shift=MISREGISTRATION)[band], 600.0, 0.4),
        )
        add(
            file=name,
            camera=MONO,
            kind="registration",
            exposure_time_s=0.4,
            wavelength_nm=600.0,
            rotation=rotation,
        )

    # dark frames for every exposure time of the spectral camera, 6 frames each
    dark_times = sorted({r["exposure_time_s"] for r in rows if r["camera"] == MONO})
    for k, t in enumerate(dark_times):
        for f in range(6):
            name = save(root, f"{SESSION}/darks/t{k:02d}_{f}.tif", mono_counts(rng, None, None, t))
            add(file=name, camera=MONO, kind="dark", exposure_time_s=t)

    with open(root / "manifest.csv", "w", newline="", encoding="utf-8") as out:
        writer = csv.DictWriter(out, fieldnames=COLUMNS, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: ("" if row.get(k) is None else row.get(k)) for k in COLUMNS})

    calibration = root / "calibration"
    calibration.mkdir(exist_ok=True)
    fine = np.arange(380.0, 781.0, 2.0)  # the LED measured by a spectrometer, 2 nm steps
    write_table(
        calibration / "illuminant.csv",
        ["wavelength_nm", "value"],
        zip(fine, illuminant(fine), strict=True),
    )
    coarse = np.arange(400.0, 731.0, 5.0)  # the white target's certificate, 5 nm steps
    write_table(
        calibration / "white_reference.csv",
        ["wavelength_nm", "reflectance"],
        ((w, 0.97) for w in coarse),
    )
    write_table(
        calibration / "colour_checker.csv",
        ["patch", "wavelength_nm", "reflectance"],
        (
            (f"P{p + 1:02d}", wl, chart[p, b])
            for p in range(chart.shape[0])
            for b, wl in enumerate(WAVELENGTHS)
        ),
    )
    tifffile.imwrite(calibration / "chart_labels.tif", patches, photometric="minisblack")
    for camera in cameras:
        if camera != PAIRED:
            tifffile.imwrite(
                calibration / f"chart_labels_{camera}.tif",
                np.roll(patches, CHART_OFFSET[camera], axis=(0, 1)),
                photometric="minisblack",
            )
    if power:  # the lab's measurement of each LED's power (0.3 % repeatability)
        measured = np.random.default_rng(5).normal(1.0, 0.003, 6)
        write_table(
            calibration / "led_power.csv",
            ["led", "relative_power"],
            (
                (led, float(power.get(led, 1.0) * m))
                for led, m in zip(range(100, 106), measured, strict=True)
            ),
        )
    models = {camera: cameras[camera][2] for camera in cameras}
    (root / "capture.toml").write_text(
        "\n".join(
            [
                "# written by the gantry control software of another lab",
                f'name = "{LAB["name"]}"',
                f"rotation_step_deg = {ROTATION_STEP}",
                "",
                "[rgb]",
                f"cameras = [{', '.join(repr(c).replace(chr(39), chr(34)) for c in cameras)}]",
                "bit_depth = 12",
                f'paired_camera = "{PAIRED}"',
                "",
                "[spectral]",
                f'camera = "{MONO}"',
                "bit_depth = 12",
                "",
                "[exposure_plan]",
                f"t0 = {T0}",
                f"s0 = {S0}",
                f"omega = {OMEGA}",
                "",
                "[rgb.models]",
                *[f'"{camera}" = "{model}"' for camera, model in models.items()],
                "",
                "[colour_checker]",
                'patch_index = "calibration/chart_labels.tif"',
                "",
                "[colour_checker.patch_indices]",
                *[
                    f'"{camera}" = "calibration/chart_labels_{camera}.tif"'
                    for camera in cameras
                    if camera != PAIRED
                ],
                "",
            ]
        ),
        encoding="utf-8",
    )
    if truth is not None:
        yy, xx = supersampled(0.0, 0.0, factor=1)
        np.savez(
            truth,
            material=material_at(yy[..., 0, 0], xx[..., 0, 0]),
            reflectance=material_reflectances(WAVELENGTHS),
            illuminant=illuminant(WAVELENGTHS),
            wavelength=WAVELENGTHS,
            cameras=np.array(list(cameras)),
            sensitivity=np.stack([rgb_sensitivity(WAVELENGTHS, c) for c in cameras]),
            camera_model=np.array([cameras[c][2] for c in cameras]),
            led_power=np.array([power.get(led, 1.0) for led in range(100, 106)]),
            falloff_rgb=rgb_falloff(),
            falloff_spectral=np.stack([mono_falloff(float(w)) for w in WAVELENGTHS]),
        )
    return root


def write_table(path: Path, header: list[str], rows) -> None:
    with open(path, "w", newline="", encoding="utf-8") as out:
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(header)
        for row in rows:
            writer.writerow([f"{v:.6g}" if isinstance(v, float | np.floating) else v for v in row])


LAB.update(default_lab())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--truth", type=Path, default=None)
    args = parser.parse_args(argv)
    write_capture(args.out, args.truth)
    leaked = sorted(name for name in sys.modules if name.split(".")[0] == "spectralize")
    print(f"wrote {args.out}; spectralize modules imported: {leaked}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
