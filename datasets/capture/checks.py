"""The rules a capture's manifest rows keep, by row and together, given its ``capture.toml``.

Pure functions of parsed rows (:func:`~.manifest.parse_manifest`) and the config
(:func:`~.config.parse_config`): each returns the problems it finds, naming the manifest line.

- :func:`check_rows`: per row, by kind and camera (which columns a kind needs, ranges);
- :func:`check_structure`: duplicates, contradicting rows and the exposure series a run needs;
- :func:`check_frame_shapes` and :func:`check_bands`: the probed files and the calibration
  series against the rows.

References
----------
Fast Capture of Spectral Image Series, sec. 3 (pairing band shots with RGB images seen from the
same angles) and sec. 4 (exposure series for the OECFs and the spectral calibration).
"""

from __future__ import annotations

from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from spectralize.schemas import Problem

from .images import IMAGE_SUFFIXES
from .model import ANGLE_RANGE, ANGLES, MANIFEST, Config, Row, rounded

__all__ = [
    "check_rows",
    "frame_key",
    "check_structure",
    "pair",
    "calibration_cameras",
    "borrowed_calibration",
    "check_calibration_cameras",
    "check_frame_shapes",
    "calibration_bands",
    "check_bands",
]


def check_rows(rows: list[Row], config: Config) -> tuple[list[Row], list[Problem]]:
    """Per-row rules by kind and camera; rows that break one are dropped (and reported).

    Returns
    -------
    kept, problems
        The rows that keep every rule, and one problem per broken rule (manifest line, column).
    """
    problems: list[Problem] = []
    kept = []
    for row in rows:
        bad = len(problems)
        rgb_camera = row.camera in config.rgb_cameras
        mono = row.camera == config.spectral_camera
        if not (rgb_camera or mono):
            problems.append(
                Problem(
                    f"{row.where}: camera",
                    f"an RGB camera {list(config.rgb_cameras)} or the spectral camera "
                    f"{config.spectral_camera!r} of capture.toml",
                    repr(row.camera),
                )
            )
        elif row.kind in ("rgb",) and not rgb_camera:
            problems.append(
                Problem(f"{row.where}: camera", "an RGB camera for kind rgb", repr(row.camera))
            )
        elif row.kind in ("spectral", "dark") and not mono:
            problems.append(
                Problem(
                    f"{row.where}: camera", f"the spectral camera for kind {row.kind}", repr(row.camera)
                )
            )
        elif row.kind == "registration" and rgb_camera:
            if row.camera != config.paired_camera:
                problems.append(
                    Problem(
                        f"{row.where}: camera",
                        f"the paired RGB camera {config.paired_camera!r} or the spectral camera",
                        repr(row.camera),
                    )
                )
        if row.exposure_time is None or not row.exposure_time > 0:
            problems.append(
                Problem(f"{row.where}: exposure_time_s", "a positive time [s]", repr(row.exposure_time))
            )
        band = mono and row.kind in ("spectral", "white_reference", "colour_checker", "registration")
        if band and row.wavelength is None:
            what = "a band shot" if row.kind == "spectral" else "a spectral calibration shot"
            problems.append(
                Problem(f"{row.where}: wavelength_nm", f"the filter's wavelength for {what}", "nothing")
            )
        elif not band and row.wavelength is not None:
            problems.append(
                Problem(
                    f"{row.where}: wavelength_nm",
                    "nothing (only band shots and spectral calibration shots have one)",
                    repr(row.wavelength),
                )
            )
        elif row.wavelength is not None and not 300 <= row.wavelength <= 1100:
            problems.append(Problem(f"{row.where}: wavelength_nm", "300..1100 nm", repr(row.wavelength)))
        if row.kind in ("rgb", "spectral", "registration") and row.rotation is None:
            problems.append(Problem(f"{row.where}: rotation", "a rotation stage position", "nothing"))
        if row.kind in ("rgb", "spectral"):
            if row.led is None:
                problems.append(Problem(f"{row.where}: led", "the index of the LED", "nothing"))
            for name, angle in zip(ANGLES, row.angles, strict=True):
                lo, hi = ANGLE_RANGE[name]
                if angle is None or not lo <= angle <= hi:
                    problems.append(
                        Problem(
                            f"{row.where}: {name}", f"an angle in {lo:g}..{hi:g} degree", repr(angle)
                        )
                    )
        if Path(row.file).suffix.lower() not in IMAGE_SUFFIXES:
            problems.append(Problem(f"{row.where}: file", "a .tif, .tiff or .png file", repr(row.file)))
        if len(problems) == bad:
            kept.append(row)
    return kept, problems


def frame_key(row: Row) -> tuple:
    """What a row measures: two rows with one key are duplicates (dark: every file counts)."""
    t = rounded(row.exposure_time)
    wl = None if row.wavelength is None else rounded(row.wavelength)
    if row.kind == "rgb":
        return (row.kind, row.camera, row.rotation, row.led, t)
    if row.kind == "spectral":
        return (row.kind, row.rotation, row.led, wl)
    if row.kind == "dark":
        return (row.kind, row.file)
    if row.kind == "registration":
        return (row.kind, row.camera, row.rotation)
    return (row.kind, row.camera, wl, t)


def check_structure(rows: list[Row], config: Config) -> list[Problem]:
    """Duplicates, contradictions and the shape of every exposure series, over all rows.

    A band shot must pair with an RGB image of the paired camera seen from the same four
    angles (:func:`pair`); dark frames, the calibration targets' exposure series and the
    registration shots must have the layout their raw groups need.
    """
    images = _rgb_images(rows)
    problems = _check_duplicates(rows)
    problems += _check_rgb_series(images)
    problems += _check_band_pairs(rows, images, config)
    problems += _check_dark_frames(rows)
    # calibration targets: an RGB series per RGB camera that photographed them (the paired
    # camera always), and a band series per wavelength, one set of times
    problems += check_calibration_cameras(rows, config)
    problems += _check_target_band_series(rows, config)
    problems += _check_registration(rows, config)
    for kind in ("rgb", "spectral"):
        if not any(r.kind == kind for r in rows):
            problems.append(Problem(MANIFEST, f"frames of kind {kind}", "none"))
    return problems


def _check_duplicates(rows: list[Row]) -> list[Problem]:
    """Each file listed once, and one file per frame (:func:`frame_key`)."""
    problems: list[Problem] = []
    seen_file: dict[str, Row] = {}
    seen_key: dict[tuple, Row] = {}
    for row in rows:
        if row.file in seen_file:
            problems.append(
                Problem(
                    row.where, "each file listed once", f"a duplicate of line {seen_file[row.file].line}"
                )
            )
            continue
        seen_file[row.file] = row
        key = frame_key(row)
        if key in seen_key:
            problems.append(
                Problem(
                    row.where,
                    "one file per frame",
                    f"the same {row.kind} frame as line {seen_key[key].line} ({seen_key[key].file})",
                )
            )
        seen_key[key] = row
    return problems


def _rgb_images(rows: list[Row]) -> dict[tuple, list[Row]]:
    """The rows of each RGB image, ``{(camera, rotation, led): its exposure series}``."""
    images: dict[tuple, list[Row]] = defaultdict(list)
    for row in rows:
        if row.kind == "rgb":
            images[(row.camera, row.rotation, row.led)].append(row)
    return images


def _check_rgb_series(images: dict[tuple, list[Row]]) -> list[Problem]:
    """RGB images: one series each, equal lengths, consistent angles, at least two times."""
    problems: list[Problem] = []
    lengths = Counter(len(series) for series in images.values())
    common = lengths.most_common(1)[0][0] if lengths else 0
    for (camera, rotation, led), series in images.items():
        label = f"RGB image camera={camera} rotation={rotation} led={led}"
        lines = ", ".join(str(r.line) for r in series)
        if len({rounded(r.exposure_time) for r in series}) < 2:
            problems.append(
                Problem(
                    f"{label} ({MANIFEST} lines {lines})",
                    "an exposure series of at least two exposure times",
                    f"one time ({series[0].exposure_time:g} s)",
                )
            )
        elif len(series) != common:
            problems.append(
                Problem(
                    f"{label} ({MANIFEST} lines {lines})",
                    f"{common} exposures, like the other images",
                    f"{len(series)} exposures",
                )
            )
        first = series[0]
        for row in series[1:]:
            for name, a, b in zip(ANGLES, first.angles, row.angles, strict=True):
                if abs(a - b) > 1e-6:
                    problems.append(
                        Problem(
                            f"{row.where}: {name}",
                            f"{a:g} as on line {first.line} (the same image)",
                            f"{b:g} (contradicting rows)",
                        )
                    )
    return problems


def _check_band_pairs(rows: list[Row], images: dict[tuple, list[Row]], config: Config) -> list[Problem]:
    """Each band shot pairs with an RGB image of the paired camera seen from the same angles."""
    problems: list[Problem] = []
    paired = [(k, s[0]) for k, s in images.items() if k[0] == config.paired_camera]
    for row in rows:
        if row.kind != "spectral":
            continue
        if pair(row, paired, config.angle_tolerance) is None:
            problems.append(
                Problem(
                    f"{row.where}",
                    f"an RGB image of the paired camera {config.paired_camera!r} with the same "
                    f"angles (within {config.angle_tolerance:g} degree)",
                    "none: " + ", ".join(f"{n}={a:g}" for n, a in zip(ANGLES, row.angles, strict=True)),
                )
            )
    return problems


def _check_dark_frames(rows: list[Row]) -> list[Problem]:
    """Dark frames: at least two per exposure time, as many at every time."""
    dark = Counter(rounded(r.exposure_time) for r in rows if r.kind == "dark")
    if not dark:
        return [Problem(MANIFEST, "dark frames (kind dark) of the spectral camera", "none")]
    if len(set(dark.values())) > 1:
        counts = ", ".join(f"{t:g} s: {n}" for t, n in sorted(dark.items()))
        return [Problem(f"{MANIFEST}: dark", "the same number of frames per exposure time", counts)]
    if min(dark.values()) < 2:
        return [Problem(f"{MANIFEST}: dark", "at least 2 frames per exposure time", "1")]
    return []


def _check_target_band_series(rows: list[Row], config: Config) -> list[Problem]:
    """The calibration targets' band series: one per wavelength, one set of exposure times."""
    problems: list[Problem] = []
    for kind in ("white_reference", "colour_checker"):
        mono = [r for r in rows if r.kind == kind and r.camera == config.spectral_camera]
        times: dict[float, set[float]] = defaultdict(set)
        for r in mono:
            times[rounded(r.wavelength)].add(rounded(r.exposure_time))
        if not times:
            problems.append(
                Problem(
                    f"{MANIFEST}: {kind} (camera {config.spectral_camera})",
                    "band exposure series",
                    "none",
                )
            )
            continue
        reference = max(times.values(), key=len)
        for wl, ts in sorted(times.items()):
            if len(ts) < 2:
                problems.append(
                    Problem(
                        f"{MANIFEST}: {kind} at {wl:g} nm",
                        "an exposure series of at least two exposure times",
                        "one time",
                    )
                )
            elif ts != reference:
                problems.append(
                    Problem(
                        f"{MANIFEST}: {kind} at {wl:g} nm",
                        f"the exposure times of the other bands {sorted(reference)}",
                        f"{sorted(ts)}",
                    )
                )
    return problems


def _check_registration(rows: list[Row], config: Config) -> list[Problem]:
    """Registration: one RGB and one band shot per rotation, one time per camera."""
    problems: list[Problem] = []
    reg = [r for r in rows if r.kind == "registration"]
    for camera in (config.paired_camera, config.spectral_camera):
        mine = [r for r in reg if r.camera == camera]
        if not mine:
            problems.append(
                Problem(
                    f"{MANIFEST}: registration", f"one shot per rotation of camera {camera!r}", "none"
                )
            )
            continue
        for name, values in (
            ("exposure_time_s", {rounded(r.exposure_time) for r in mine}),
            (
                "wavelength_nm",
                {r.wavelength for r in mine} if camera == config.spectral_camera else {None},
            ),
        ):
            if len(values) > 1:
                problems.append(
                    Problem(
                        f"{MANIFEST}: registration, camera {camera}: {name}",
                        "one value for all rotations",
                        f"{sorted(values)} (contradicting rows)",
                    )
                )
    rotations = [
        {r.rotation for r in reg if r.camera == c}
        for c in (config.paired_camera, config.spectral_camera)
    ]
    if all(rotations) and rotations[0] != rotations[1]:
        problems.append(
            Problem(
                f"{MANIFEST}: registration",
                "RGB and spectral shots at the same rotations",
                f"{sorted(rotations[0])} and {sorted(rotations[1])}",
            )
        )
    return problems


def calibration_cameras(rows: list[Row], config: Config) -> list[str]:
    """The RGB cameras with their own calibration-target frames, in ``rgb.cameras`` order."""
    own = {r.camera for r in rows if r.kind in ("white_reference", "colour_checker")}
    return [c for c in config.rgb_cameras if c in own]


def borrowed_calibration(config: Config, cameras: list[str]) -> dict[str, str]:
    """``{camera: lender}`` for RGB cameras without chart frames of their own: the first
    camera with frames that ``rgb.models`` says is of the same sensor model."""
    out = {}
    for camera in config.rgb_cameras:
        if camera in cameras or config.model_of(camera) is None:
            continue
        same = [c for c in cameras if config.model_of(c) == config.model_of(camera)]
        if same:
            out[camera] = same[0]
    return out


def check_calibration_cameras(rows: list[Row], config: Config) -> list[Problem]:
    """Each RGB camera photographs the white reference and the colour checker (an exposure
    series each, as many exposures as the other cameras), or borrows the calibration of a
    camera that ``rgb.models`` in ``capture.toml`` says is of the same model; the paired
    camera always has its own."""
    problems: list[Problem] = []
    cameras = calibration_cameras(rows, config)
    borrowed = borrowed_calibration(config, cameras)
    counts: dict[str, dict[str, int]] = defaultdict(dict)
    for camera in config.rgb_cameras:
        if camera not in cameras:
            if camera in borrowed:
                continue
            model = config.model_of(camera)
            problems.append(
                Problem(
                    f"{MANIFEST}: white_reference, colour_checker (camera {camera})",
                    f"an exposure series of the white reference and the colour checker by RGB camera "
                    f"{camera!r} (each camera is calibrated on its own), or in capture.toml rgb.models "
                    f"the same model as a camera that has them",
                    "no frames"
                    + (
                        f"; rgb.models says {model!r}, which no camera with chart frames has"
                        if model is not None
                        else ""
                    ),
                )
            )
            continue
        for kind in ("white_reference", "colour_checker"):
            series = [r for r in rows if r.kind == kind and r.camera == camera]
            times = {rounded(r.exposure_time) for r in series}
            counts[kind][camera] = len(series)
            if len(times) < 2:
                lines = ", ".join(str(r.line) for r in series)
                problems.append(
                    Problem(
                        f"{MANIFEST}: {kind} (camera {camera}" + (f", lines {lines})" if lines else ")"),
                        "an exposure series of at least two exposure times",
                        f"{len(series)} frame(s)" if len(series) < 2 else "one time",
                    )
                )
    for kind, per_camera in counts.items():
        if len(set(per_camera.values())) > 1:
            problems.append(
                Problem(
                    f"{MANIFEST}: {kind}",
                    "the same number of RGB exposures for every camera",
                    ", ".join(f"{c}: {n}" for c, n in per_camera.items()),
                )
            )
    return problems


def pair(row: Row, paired: list[tuple[tuple, Row]], tolerance: float) -> tuple | None:
    """The key of the first RGB image in ``paired`` seen from the angles of band shot ``row``.

    Angles agree within ``tolerance`` [degree] (azimuths modulo 360); ``None`` when no image
    does.
    """

    def distance(a: float, b: float, periodic: bool) -> float:
        d = abs(a - b)
        return min(d, 360.0 - d) if periodic else d

    for key, image in paired:
        if all(
            distance(a, b, name.startswith("phi")) <= tolerance
            for name, a, b in zip(ANGLES, row.angles, image.angles, strict=True)
        ):
            return key
    return None


def check_frame_shapes(
    probed: list[tuple[Row, tuple[int, int]]], frame_shape: tuple[int, int] | None
) -> list[Problem]:
    """Every probed file has the run's frame shape (all frames of a run share one size)."""
    return [
        Problem(
            row.where,
            f"frames of {frame_shape[0]} x {frame_shape[1]} px like the others",
            f"{shape[0]} x {shape[1]} px",
        )
        for row, shape in probed
        if shape != frame_shape
    ]


def calibration_bands(rows: list[Row]) -> np.ndarray:
    """The wavelengths of the white reference's band series [nm]: the calibration's bands."""
    return np.asarray(
        np.unique(
            [
                rounded(r.wavelength)
                for r in rows
                if r.kind == "white_reference" and r.wavelength is not None
            ]
        ),
        dtype=float,
    )


def check_bands(rows: list[Row], bands: np.ndarray) -> list[Problem]:
    """Band shots and the colour checker's band series lie on the white reference's bands."""
    problems: list[Problem] = []
    band_shots = {rounded(r.wavelength) for r in rows if r.kind == "spectral"}
    missing = sorted(band_shots - set(bands.tolist()))
    if missing and bands.size:
        problems.append(
            Problem(
                f"{MANIFEST}: white_reference",
                "a calibration series at every wavelength of the band shots",
                f"none at {missing} nm",
            )
        )
    checker_bands = sorted(
        {rounded(r.wavelength) for r in rows if r.kind == "colour_checker" and r.wavelength}
    )
    if bands.size and checker_bands and checker_bands != bands.tolist():
        problems.append(
            Problem(
                f"{MANIFEST}: colour_checker",
                f"the white reference's bands {bands.tolist()}",
                f"{checker_bands}",
            )
        )
    return problems
