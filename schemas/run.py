"""The data contract of a measurement run store.

One measurement run is one zarr v3 directory. Each group below is an :class:`xarray.Dataset`
a user can open with ``xarray.open_zarr(path, group=..., consolidated=False)``.
The table in ``schemas/README.md`` is rendered from these definitions
(``python -m spectralize.schemas``) and a test keeps the two in step.

Units follow CF conventions: ``"DN"`` for raw digital numbers, ``"1"`` for relative
(dimensionless) radiance, ``"nm"``, ``"s"``, ``"degree"``, ``"px"``.
"""

from __future__ import annotations

from collections.abc import Iterable

from .errors import SpectralizeError
from .spec import ArraySpec, GroupSchema, Precision

__all__ = [
    "GROUP_SCHEMAS",
    "register_schema",
    "schema_for",
    "image_coords",
    "shot_coords",
    "RAW_DARK",
    "RAW_RGB",
    "RAW_SPECTRAL",
    "RAW_EXPOSURE_PLAN",
    "RAW_WHITE_REFERENCE",
    "RAW_COLOUR_CHECKER",
    "RAW_REGISTRATION",
    "TRUTH_CAMERA",
    "EVALUATION",
    "DARK",
    "HDR",
    "BANDS",
    "REGISTRATION",
    "IMAGE_SETS",
    "ENDMEMBER_LIBRARY",
    "SPECTRA",
    "SPECTRA_SEED",
    "SPECTRA_PRECISION",
    "CAMERA_MATRIX",
    "TRUTH_SPECTRA",
    "CALIBRATION_OECF_RGB",
    "CALIBRATION_OECF_SPECTRAL",
    "CALIBRATION_SPECTRAL",
]


def image_coords(dim: str = "image") -> tuple[ArraySpec, ...]:
    """Per-image coords: which camera, rotation and LED took it, and its BTF angles."""
    return (
        ArraySpec("camera", (dim,), "kind:iu", None, "RGB camera index on the gantry arc"),
        ArraySpec("rotation", (dim,), "kind:iu", None, "sample rotation step (15 degree steps)"),
        ArraySpec("led", (dim,), "kind:iu", None, "index of the LED that lit the sample"),
        ArraySpec("theta_i", (dim,), "kind:f", "degree", "light elevation from the normal", (0, 90)),
        ArraySpec("phi_i", (dim,), "kind:f", "degree", "light azimuth", (0, 360)),
        ArraySpec("theta_o", (dim,), "kind:f", "degree", "view elevation from the normal", (0, 90)),
        ArraySpec("phi_o", (dim,), "kind:f", "degree", "view azimuth", (0, 360)),
    )


def shot_coords(dim: str = "shot") -> tuple[ArraySpec, ...]:
    """Per-shot coords of band-filtered monochrome frames."""
    return (
        ArraySpec(
            "wavelength",
            (dim,),
            "kind:f",
            "nm",
            "centre wavelength of the tunable filter",
            (300, 1100),
            finite=True,
        ),
        ArraySpec("exposure_time", (dim,), "kind:f", "s", "exposure time", (0, 1e4), finite=True),
        ArraySpec("image", (dim,), "kind:iu", None, "index of the RGB image the shot pairs with"),
        ArraySpec("rotation", (dim,), "kind:iu", None, "sample rotation step"),
        ArraySpec("led", (dim,), "kind:iu", None, "index of the LED that lit the sample"),
    )


RAW_DARK = GroupSchema(
    name="raw/dark",
    description="raw dark frames (closed shutter) of the spectral camera, many per exposure time",
    variables=(
        ArraySpec("frames", ("exposure_time", "frame", "y", "x"), "uint16", "DN", "raw dark frame"),
    ),
    coords=(
        ArraySpec(
            "exposure_time", ("exposure_time",), "kind:f", "s", "exposure time", (0, 1e4), finite=True
        ),
    ),
    attrs={"camera": "which camera took the frames", "bit_depth": "ADC bit depth, 8..16"},
)

RAW_RGB = GroupSchema(
    name="raw/rgb",
    description="LDR exposure series of the RGB cameras, one series per image",
    variables=(
        ArraySpec(
            "counts", ("image", "exposure", "y", "x", "channel"), "uint16", "DN", "raw RGB pixel value"
        ),
    ),
    coords=(
        ArraySpec(
            "exposure_time", ("image", "exposure"), "kind:f", "s", "exposure time", (0, 1e4), finite=True
        ),
        ArraySpec("channel", ("channel",), "kind:UOT", None, "colour channel"),
        *image_coords(),
    ),
    attrs={"bit_depth": "ADC bit depth, 8..16"},
)

RAW_SPECTRAL = GroupSchema(
    name="raw/spectral",
    description="very short, very noisy band-filtered frames of the monochrome camera",
    variables=(
        ArraySpec("counts", ("shot", "y", "x"), "uint16", "DN", "raw band-filtered pixel value"),
    ),
    coords=shot_coords(),
    attrs={"bit_depth": "ADC bit depth, 8..16"},
)

DARK = GroupSchema(
    name="dark",
    description="per-pixel mean and standard deviation of the dark frames, per exposure time",
    variables=(
        ArraySpec("mean", ("exposure_time", "y", "x"), "float32", "DN", "mean dark frame"),
        ArraySpec(
            "std",
            ("exposure_time", "y", "x"),
            "float32",
            "DN",
            "per-pixel standard deviation of the dark frames",
        ),
    ),
    coords=(
        ArraySpec(
            "exposure_time", ("exposure_time",), "kind:f", "s", "exposure time", (0, 1e4), finite=True
        ),
    ),
    attrs={"frame_count": "number of dark frames averaged per exposure time"},
)

HDR = GroupSchema(
    name="hdr",
    description="HDR RGB radiance merged from the exposure series",
    variables=(
        ArraySpec(
            "radiance",
            ("image", "y", "x", "channel"),
            "float32",
            "1",
            "relative RGB radiance",
            finite=True,
        ),
    ),
    coords=(ArraySpec("channel", ("channel",), "kind:UOT", None, "colour channel"), *image_coords()),
)

BANDS = GroupSchema(
    name="bands",
    description="calibrated, registered noisy band radiance with the filter size of its band",
    # finite: the reconstruction's data term (eq. 1) has no use for NaN, and refuses it
    variables=(
        ArraySpec("radiance", ("shot", "y", "x"), "float32", "1", "relative band radiance", finite=True),
    ),
    coords=(
        *shot_coords(),
        ArraySpec(
            "filter_size",
            ("shot",),
            "kind:f",
            "px",
            "Gaussian filter size s_i (eq. 3)",
            (0, 1e5),
            finite=True,
        ),
    ),
)

_SPECTRA_VARIABLES = (
    ArraySpec(
        "radiance", ("image", "wavelength", "y", "x"), "float32", "1", "relative spectral radiance"
    ),
)
_SPECTRA_COORDS = (
    ArraySpec("wavelength", ("wavelength",), "kind:f", "nm", "wavelength", (300, 1100), finite=True),
    *image_coords(),
)

_CONFIDENCE = ArraySpec(
    "confidence",
    ("image", "y", "x"),
    "float32",
    "1",
    "estimated per-pixel nRMSE of the spectra (higher: trust less)",
)

SPECTRA_PRECISION = Precision(keepbits=10)
"""The reconstructed cube's stored precision: 10 mantissa bits, every value within
``2 ** -11`` relative of the computed one, far finer than the reconstruction knows it
(sec. 5). Only the final cube: the seed set's spectra, which warm-start the other sets, and
the ground truth keep every bit."""

SPECTRA = GroupSchema(
    name="spectra",
    description="reconstructed spectral cube (eq. 1), chunked per image and tile",
    variables=(
        ArraySpec(
            "radiance",
            ("image", "wavelength", "y", "x"),
            "float32",
            "1",
            "relative spectral radiance",
            precision=SPECTRA_PRECISION,
        ),
    ),
    coords=_SPECTRA_COORDS,
    optional_variables=(_CONFIDENCE,),
)

CAMERA_MATRIX = GroupSchema(
    name="camera_matrix",
    description="any group with the RGB camera matrix C (calibration/spectral, truth/camera)",
    variables=(
        ArraySpec(
            "camera_matrix", ("channel", "wavelength"), "kind:f", None, "RGB camera matrix C: RGB = C S"
        ),
    ),
    coords=(
        ArraySpec("wavelength", ("wavelength",), "kind:f", "nm", "wavelength", (300, 1100), finite=True),
    ),
)

SPECTRA_SEED = GroupSchema(
    name="spectra_seed",
    description="spectra of the seed image set, solved first to warm-start the others",
    variables=(
        *_SPECTRA_VARIABLES,
        # per image, not an attr: a tiled seed set is written as it is solved, tile by tile
        ArraySpec(
            "iterations",
            ("image",),
            "kind:iu",
            None,
            "solver iterations of the seed set (the most over its tiles)",
        ),
    ),
    coords=_SPECTRA_COORDS,
    # optional: stores written before the seed set kept it have none (recomputed then)
    optional_variables=(_CONFIDENCE,),
    attrs={"seed_set": "index of the seed set"},
)

TRUTH_SPECTRA = GroupSchema(
    name="truth/spectra",
    description="ground-truth spectral cube of a simulated run (evaluation only)",
    variables=_SPECTRA_VARIABLES,
    coords=_SPECTRA_COORDS,
)


# -- calibration shots, registration shots, the exposure plan and simulated truth --------
def _counts(name: str, dims: tuple[str, ...], long_name: str) -> ArraySpec:
    return ArraySpec(name, dims, "uint16", "DN", long_name)


_WL = ArraySpec(
    "wavelength",
    ("wavelength",),
    "kind:f",
    "nm",
    "centre wavelength of the band",
    (300, 1100),
    finite=True,
)
_CHANNEL = ArraySpec("channel", ("channel",), "kind:UOT", None, "colour channel")
_CALIBRATION_VARIABLES = (
    _counts(
        "rgb_counts",
        ("camera", "rgb_exposure", "y", "x", "channel"),
        "RGB exposure series of each RGB camera that photographed the target",
    ),
    _counts(
        "spectral_counts",
        ("wavelength", "spectral_exposure", "y", "x"),
        "exposure series of every band of the spectral camera",
    ),
    ArraySpec(
        "illuminant",
        ("wavelength",),
        "kind:f",
        "1",
        "measured relative spectral radiance of the LEDs",
        (0, 1e6),
        finite=True,
    ),
)
_CALIBRATION_COORDS = (
    _WL,
    _CHANNEL,
    ArraySpec("camera", ("camera",), "kind:iu", "1", "RGB camera index (raw/rgb camera)"),
    ArraySpec(
        "rgb_exposure_time",
        ("camera", "rgb_exposure"),
        "kind:f",
        "s",
        "exposure time",
        (0, 1e4),
        finite=True,
    ),
    ArraySpec(
        "spectral_exposure_time",
        ("spectral_exposure",),
        "kind:f",
        "s",
        "exposure time",
        (0, 1e4),
        finite=True,
    ),
)
_CALIBRATION_ATTRS = {
    "rgb_bit_depth": "ADC bit depth of the RGB camera",
    "spectral_bit_depth": "ADC bit depth of the spectral camera",
}

RAW_EXPOSURE_PLAN = GroupSchema(
    name="raw/exposure_plan",
    description="exposure time and Gaussian filter size per band (eq. 2, 3) and their cost",
    variables=(
        ArraySpec(
            "exposure_time",
            ("wavelength",),
            "kind:f",
            "s",
            "exposure time (eq. 2)",
            (0, 1e4),
            finite=True,
        ),
        ArraySpec(
            "filter_size",
            ("wavelength",),
            "kind:f",
            "px",
            "filter size s_i (eq. 3)",
            (0, 1e5),
            finite=True,
        ),
        ArraySpec("filter_sigma", ("wavelength",), "kind:f", "px", "s_i / 5", (0, 1e5), finite=True),
        ArraySpec("spectral_capture_time", (), "kind:f", "s", "total spectral exposure"),
        ArraySpec("rgb_capture_time", (), "kind:f", "s", "total RGB exposure"),
    ),
    coords=(_WL,),
    attrs={"t0": "constant of eq. 2", "s0": "constant of eq. 3", "omega": "exponent of eq. 2"},
)
RAW_WHITE_REFERENCE = GroupSchema(
    name="raw/white_reference",
    description="white diffuse target under the LEDs: RGB and per-band exposure series",
    variables=_CALIBRATION_VARIABLES
    + (
        ArraySpec(
            "target_reflectance",
            ("wavelength",),
            "kind:f",
            "1",
            "certified reflectance of the white target",
            (0, 1),
            finite=True,
        ),
    ),
    coords=_CALIBRATION_COORDS,
    attrs=_CALIBRATION_ATTRS,
)
RAW_COLOUR_CHECKER = GroupSchema(
    name="raw/colour_checker",
    description="ColorChecker chart under the LEDs: RGB and per-band exposure series",
    variables=_CALIBRATION_VARIABLES
    + (
        ArraySpec(
            "patch_reflectance",
            ("patch", "wavelength"),
            "kind:f",
            "1",
            "published reflectance of the patches",
            (0, 1),
            finite=True,
        ),
        ArraySpec(
            "patch_index",
            ("y", "x"),
            "kind:iu",
            "1",
            "patch under each pixel of the paired RGB camera (and the spectral camera), -1 on the frame",
        ),
        ArraySpec(
            "rgb_patch_index",
            ("camera", "y", "x"),
            "kind:iu",
            "1",
            "patch under each pixel of each RGB camera, -1 on the frame",
        ),
    ),
    coords=_CALIBRATION_COORDS + (ArraySpec("patch_name", ("patch",), "kind:UOT", None, "patch name"),),
    attrs=_CALIBRATION_ATTRS | {"chart": "name of the chart's reflectance data"},
)
RAW_REGISTRATION = GroupSchema(
    name="raw/registration",
    description="long-exposure shots per rotation of the 45 deg RGB and the spectral camera",
    variables=(
        _counts("rgb_counts", ("rotation", "y", "x", "channel"), "RGB camera at 45 deg"),
        _counts("spectral_counts", ("rotation", "y", "x"), "spectral camera"),
    ),
    coords=(
        ArraySpec("rotation", ("rotation",), "kind:iu", "1", "rotation stage position"),
        ArraySpec(
            "rotation_angle", ("rotation",), "kind:f", "degree", "sample rotation", (0, 360), finite=True
        ),
        _CHANNEL,
        ArraySpec("rgb_exposure_time", (), "kind:f", "s", "exposure time", (0, 1e4)),
        ArraySpec("spectral_exposure_time", (), "kind:f", "s", "exposure time", (0, 1e4)),
        ArraySpec("spectral_wavelength", (), "kind:f", "nm", "filter band", (300, 1100)),
    ),
    attrs=_CALIBRATION_ATTRS,
)
TRUTH_CAMERA = GroupSchema(
    name="truth/camera",
    description="true camera parameters of a simulated run (evaluation only)",
    variables=(
        ArraySpec(
            "camera_matrix",
            ("channel", "wavelength"),
            "kind:f",
            "s-1",
            "RGB camera matrix C",
            (0, 1e9),
            finite=True,
        ),
        ArraySpec(
            "quantum_efficiency",
            ("wavelength",),
            "kind:f",
            "s-1",
            "quantum efficiency Q per band",
            (0, 1e9),
            finite=True,
        ),
        ArraySpec("illuminant", ("wavelength",), "kind:f", "1", "LED spectrum L", (0, 1e6), finite=True),
        ArraySpec("bandpass", ("band", "wavelength"), "kind:f", "1", "filter bandpass"),
        ArraySpec(
            "oecf", ("sensor", "code"), "kind:f", "1", "exposure per code (NaN beyond the bit depth)"
        ),
        ArraySpec("adc_offset", ("sensor",), "kind:f", "DN", "mean ADC offset"),
        ArraySpec("noise_sigma", ("sensor",), "kind:f", "DN", "Gaussian noise sigma"),
        ArraySpec("bit_depth", ("sensor",), "kind:iu", "1", "ADC bit depth", (8, 16)),
        ArraySpec("spectral_adc_offset", ("y", "x"), "float32", "DN", "offset per pixel"),
        ArraySpec(
            "spectral_dark_current", ("y", "x"), "float32", "DN s-1", "dark signal rate per pixel"
        ),
        ArraySpec(
            "misregistration", ("axis",), "kind:f", "px", "spectral(p) = rgb(p - shift)", finite=True
        ),
    ),
    coords=(
        _WL,
        _CHANNEL,
        ArraySpec("band", ("band",), "kind:f", "nm", "band centre", (300, 1100)),
        ArraySpec("sensor", ("sensor",), "kind:UOT", None, "R, G, B or mono"),
        ArraySpec("code", ("code",), "kind:iu", "DN", "code value"),
        ArraySpec("axis", ("axis",), "kind:UOT", None, "y or x"),
    ),
)

REGISTRATION = GroupSchema(
    name="registration",
    description="misregistration of the spectral camera to its RGB camera (phase correlation)",
    variables=(
        ArraySpec("shift", ("axis",), "kind:f", "px", "spectral(p) = rgb(p - shift)", finite=True),
        ArraySpec("pair_shift", ("pair", "axis"), "kind:f", "px", "shift per rotation pair"),
        ArraySpec("residual", ("pair",), "kind:f", "px", "distance from the run's shift"),
    ),
    coords=(
        ArraySpec("axis", ("axis",), "kind:UOT", None, "y or x"),
        ArraySpec("rgb_rotation", ("pair",), "kind:iu", None, "rotation of the RGB shot"),
        ArraySpec("spectral_rotation", ("pair",), "kind:iu", None, "rotation of the spectral shot"),
    ),
)

IMAGE_SETS = GroupSchema(
    name="image_sets",
    description="reconstruction sets: images with band shots plus images with similar light",
    variables=(
        ArraySpec("image_set", ("image",), "kind:iu", None, "set that owns the image"),
        ArraySpec("has_bands", ("image",), "bool", None, "image has band shots"),
        ArraySpec("member", ("set", "slot"), "kind:iu", None, "image labels, -1: none"),
        ArraySpec("owned", ("set", "slot"), "bool", None, "member is owned by the set"),
    ),
    coords=(ArraySpec("image", ("image",), "kind:iu", None, "image label"),),
    attrs={"seed_set": "set solved first to warm-start the others"},
)

ENDMEMBER_LIBRARY = GroupSchema(
    name="endmember_library",
    description="the run's endmember library: material spectra learnt once from the pooled "
    "band shots of a sample of its image sets, shared by every set's solve",
    variables=(
        ArraySpec(
            "atoms",
            ("endmember", "wavelength"),
            "kind:f",
            "1",
            "endmember spectrum: relative spectral radiance under the run's light per unit "
            "channel-balanced RGB brightness (a reflectance times the light, up to scale)",
            finite=True,
        ),
        ArraySpec(
            "centre",
            ("endmember", "chromaticity"),
            "kind:f",
            "1",
            "channel-balanced RGB chromaticity of the endmember (r and g shares)",
            (0, 1),
            finite=True,
        ),
        ArraySpec(
            "channel_scale",
            ("channel",),
            "kind:f",
            "1",
            "RGB channel scale of the chromaticity (mean RGB of the pooled pixels)",
            finite=True,
        ),
        ArraySpec(
            "split_angle",
            ("endmember",),
            "kind:f",
            "degree",
            "spectral angle to the nearest endmember learnt from either half of the pooled "
            "pixels (mean of the two halves): how reproducible the fit is",
            (0, 180),
        ),
    ),
    coords=(
        ArraySpec("wavelength", ("wavelength",), "kind:f", "nm", "wavelength", (300, 1100), finite=True),
        ArraySpec(
            "highlight", ("endmember",), "bool", None, "the highlight atom (the light's spectrum)"
        ),
    ),
    attrs={"image_sets": "indices of the image sets whose band shots were pooled"},
)

# -- radiometric calibration (paper section 4) --------------------------------------------
CALIBRATION_OECF_RGB = GroupSchema(
    name="calibration/oecf_rgb",
    description="RGB camera response per camera and channel (Robertson 2003)",
    variables=(
        ArraySpec(
            "response",
            ("camera", "channel", "code"),
            "kind:f",
            "1",
            "relative exposure per pixel value (1 at the mid code)",
            finite=True,
        ),
    ),
    optional_variables=(
        ArraySpec(
            "black_level",
            ("camera",),
            "kind:iu",
            "DN",
            "each camera's black level: codes at or below it get weight 0 (the HDR merge's too)",
        ),
        ArraySpec(
            "white_level",
            ("camera",),
            "kind:iu",
            "DN",
            "the code each camera's raw values clip at: capture.toml's rgb.white_level_dn, else "
            "found in the longest exposures, else the top code",
        ),
        ArraySpec(
            "saturation",
            ("camera",),
            "kind:iu",
            "DN",
            "each camera's first saturated code (its white level less the noise): codes at or "
            "above it get weight 0 (the HDR merge's and the targets' series' too)",
        ),
    ),
    coords=(
        ArraySpec("camera", ("camera",), "kind:iu", None, "RGB camera index"),
        _CHANNEL,
        ArraySpec("code", ("code",), "kind:iu", "DN", "pixel value"),
    ),
    attrs={
        "bit_depth": "ADC bit depth",
        "black_level": "under-exposed codes (weight 0): the lowest camera's",
        "saturation": "saturated codes (weight 0): the lowest camera's",
    },
)

CALIBRATION_OECF_SPECTRAL = GroupSchema(
    name="calibration/oecf_spectral",
    description="spectral camera response over dark-subtracted values (low-SNR extension "
    "joined to Robertson)",
    variables=(
        ArraySpec(
            "response",
            ("code",),
            "kind:f",
            "1",
            "relative exposure per dark-subtracted pixel value",
            finite=True,
        ),
    ),
    coords=(
        ArraySpec("code", ("code",), "kind:f", "DN", "pixel value above the dark frame", finite=True),
    ),
    attrs={
        "bit_depth": "ADC bit depth",
        "band": "wavelength of the low-SNR series [nm]",
        "dark_level": "mean dark level [DN]",
    },
)

CALIBRATION_SPECTRAL = GroupSchema(
    name="calibration/spectral",
    description="quantum efficiency, RGB camera matrix C and cross-validation (Fig. 4)",
    variables=(
        ArraySpec(
            "quantum_efficiency",
            ("wavelength",),
            "kind:f",
            "1",
            "relative quantum efficiency per band",
            finite=True,
        ),
        ArraySpec(
            "camera_matrix", ("channel", "wavelength"), "kind:f", "1", "RGB camera matrix C", finite=True
        ),
        ArraySpec(
            "measured_rgb", ("patch", "channel"), "kind:f", "1", "HDR RGB of the colour-checker patches"
        ),
        ArraySpec(
            "predicted_rgb",
            ("patch", "channel"),
            "kind:f",
            "1",
            "RGB predicted through C from the spectral capture",
        ),
        ArraySpec(
            "relative_error", ("patch",), "kind:f", "1", "relative error of the prediction per patch"
        ),
    ),
    coords=(
        ArraySpec(
            "wavelength", ("wavelength",), "kind:f", "nm", "band centre", (300, 1100), finite=True
        ),
        _CHANNEL,
        ArraySpec("patch", ("patch",), "kind:iu", None, "colour-checker patch index"),
    ),
    # per RGB camera (raw/rgb camera index); camera_matrix above is the paired camera's
    optional_variables=(
        # calibrate_spectral v5 on: stores written before lack it
        ArraySpec(
            "illuminant",
            ("wavelength",),
            "kind:f",
            "1",
            "measured illuminant L on the band wavelengths (band radiance of a white diffuser)",
            (0, 1e6),
            finite=True,
        ),
        ArraySpec(
            "camera_matrices",
            ("camera", "channel", "wavelength"),
            "kind:f",
            "1",
            "RGB camera matrix C of each RGB camera",
            finite=True,
        ),
        ArraySpec(
            "rgb_transform",
            ("camera", "channel", "channel_in"),
            "kind:f",
            "1",
            "3 x 3 map of each camera's HDR RGB onto the paired camera's",
            finite=True,
        ),
        ArraySpec(
            "camera_relative_error",
            ("camera", "patch"),
            "kind:f",
            "1",
            "chart cross-validation per camera and patch",
        ),
        # calibrate_spectral v7 on: each camera's flat field from the white reference, as
        # Legendre coefficients over flat_term (orders flat_power_y, flat_power_x), 1 at the
        # frame centre (attrs flat_field_frame, flat_field_degree)
        ArraySpec(
            "flat_field_rgb",
            ("camera", "channel", "flat_term"),
            "kind:f",
            "1",
            "flat field of each RGB camera and channel (Legendre coefficients)",
            finite=True,
        ),
        ArraySpec(
            "flat_field_rgb_noise",
            ("camera", "channel"),
            "kind:f",
            "1",
            "noise floor of each RGB camera's flat field (NaN: borrowed map)",
        ),
        ArraySpec(
            "flat_field",
            ("wavelength", "flat_term"),
            "kind:f",
            "1",
            "flat field of the spectral camera per band (Legendre coefficients)",
            finite=True,
        ),
        ArraySpec(
            "flat_field_noise",
            ("wavelength",),
            "kind:f",
            "1",
            "noise floor of the spectral camera's flat field per band",
        ),
    ),
    attrs={
        "mean_relative_error": "mean relative error over patches",
        "max_relative_error": "largest relative error over patches",
    },
)


# -- evaluation against ground truth (simulated runs) ------------------------------------
def _map_spec(name: str, units: str, long_name: str) -> ArraySpec:
    return ArraySpec(name, ("image", "y", "x"), "float32", units, long_name)


EVALUATION = GroupSchema(
    name="evaluation",
    description="accuracy of the reconstruction against the ground truth (sec. 5, Fig. 5-7)",
    variables=(
        _map_spec("nrmse", "1", "normalised RMSE over wavelength"),
        _map_spec("spectral_angle", "degree", "spectral angle"),
        _map_spec("delta_e", "1", "CIEDE2000 colour difference"),
        ArraySpec("truth_mean", ("image",), "float64", "1", "mean ground-truth intensity"),
        ArraySpec(
            "nrmse_statistics", ("image", "statistic"), "float64", "1", "per-image nRMSE statistics"
        ),
        ArraySpec(
            "spectral_angle_statistics",
            ("image", "statistic"),
            "float64",
            "degree",
            "per-image spectral angle statistics",
        ),
        ArraySpec(
            "delta_e_statistics",
            ("image", "statistic"),
            "float64",
            "1",
            "per-image CIEDE2000 statistics",
        ),
        ArraySpec(
            "nrmse_fraction_below",
            ("image",),
            "float64",
            "1",
            "fraction of pixels with nRMSE below the threshold",
        ),
        ArraySpec("invalid_count", ("image",), "int64", "1", "pixels with undefined nRMSE"),
        ArraySpec("nrmse_histogram", ("image", "nrmse_bin"), "int64", "1", "per-image nRMSE histogram"),
        ArraySpec("nrmse_above_range", ("image",), "int64", "1", "pixels above the histogram range"),
        ArraySpec(
            "nrmse_subset_statistics",
            ("subset", "statistic"),
            "float64",
            "1",
            "nRMSE statistics per subset of images",
        ),
        ArraySpec(
            "spectral_angle_subset_statistics",
            ("subset", "statistic"),
            "float64",
            "degree",
            "spectral angle statistics per subset of images",
        ),
        ArraySpec(
            "delta_e_subset_statistics",
            ("subset", "statistic"),
            "float64",
            "1",
            "CIEDE2000 statistics per subset of images",
        ),
        ArraySpec(
            "nrmse_subset_fraction_below",
            ("subset",),
            "float64",
            "1",
            "fraction of pixels with nRMSE below the threshold, per subset",
        ),
        ArraySpec(
            "subset_pixel_count", ("subset",), "int64", "1", "pixels with a finite nRMSE, per subset"
        ),
        ArraySpec("sample_y", ("image", "sample"), "int64", "px", "row of a picked pixel"),
        ArraySpec("sample_x", ("image", "sample"), "int64", "px", "column of a picked pixel"),
        ArraySpec("sample_nrmse", ("image", "sample"), "float32", "1", "nRMSE of a picked pixel"),
        ArraySpec(
            "sample_truth",
            ("image", "sample", "wavelength"),
            "float32",
            "1",
            "ground-truth spectrum of a picked pixel",
        ),
        ArraySpec(
            "sample_reconstruction",
            ("image", "sample", "wavelength"),
            "float32",
            "1",
            "reconstructed spectrum of a picked pixel",
        ),
    ),
    coords=(
        ArraySpec("wavelength", ("wavelength",), "kind:f", "nm", "wavelength", (300, 1100), finite=True),
        ArraySpec("statistic", ("statistic",), "kind:UOT", None, "statistic: mean, median, p95, p99"),
        ArraySpec(
            "subset",
            ("subset",),
            "kind:UOT",
            None,
            "subset of images: all, with_band_shots, without_band_shots",
        ),
        ArraySpec("nrmse_bin_lower", ("nrmse_bin",), "kind:f", "1", "lower bin edge"),
        ArraySpec("nrmse_bin_upper", ("nrmse_bin",), "kind:f", "1", "upper bin edge"),
        ArraySpec(
            "sample_quantile",
            ("sample",),
            "kind:f",
            "1",
            "quantile a representative pixel was picked at",
            (0, 1),
        ),
    ),
    optional_variables=(
        ArraySpec("has_band_shots", ("image",), "bool", "1", "image has at least one band shot"),
    ),
    attrs={
        "illuminant": "illuminant of the CIEDE2000 colour difference",
        "threshold": "nRMSE level of the fraction-below statistics",
    },
)


GROUP_SCHEMAS: dict[str, GroupSchema] = {}


def register_schema(schema: GroupSchema, *, replace: bool = False) -> GroupSchema:
    """Add ``schema`` to the contract (a new node's output groups are added here)."""
    if schema.name in GROUP_SCHEMAS and not replace and GROUP_SCHEMAS[schema.name] != schema:
        raise SpectralizeError(
            f"schema {schema.name!r} is already registered with a different definition; "
            "pass replace=True to override it deliberately"
        )
    GROUP_SCHEMAS[schema.name] = schema
    return schema


for _schema in (
    RAW_DARK,
    RAW_RGB,
    RAW_SPECTRAL,
    RAW_EXPOSURE_PLAN,
    RAW_WHITE_REFERENCE,
    RAW_COLOUR_CHECKER,
    RAW_REGISTRATION,
    DARK,
    HDR,
    BANDS,
    REGISTRATION,
    IMAGE_SETS,
    ENDMEMBER_LIBRARY,
    CAMERA_MATRIX,
    SPECTRA,
    SPECTRA_SEED,
    TRUTH_SPECTRA,
    TRUTH_CAMERA,
    EVALUATION,
    CALIBRATION_OECF_RGB,
    CALIBRATION_OECF_SPECTRAL,
    CALIBRATION_SPECTRAL,
):
    register_schema(_schema)


def schema_for(name: str) -> GroupSchema:
    """The registered schema called ``name``.

    Raises
    ------
    SpectralizeError
        Listing the known schema names when ``name`` is not one of them.
    """
    try:
        return GROUP_SCHEMAS[name]
    except KeyError:
        known = ", ".join(sorted(GROUP_SCHEMAS))
        raise SpectralizeError(f"unknown schema {name!r}; known schemas: {known}") from None


def render_table(schemas: Iterable[GroupSchema] | None = None) -> str:
    """The contract as a Markdown table (what ``schemas/README.md`` shows)."""
    rows = [
        "| group | what | variables: dims dtype [units] | coords: dims dtype [units] | required attrs |",
        "|---|---|---|---|---|",
    ]

    def fmt(spec: ArraySpec) -> str:
        units = f" [{spec.units}]" if spec.units else ""
        precision = spec.precision
        stored = "" if precision is None else f", stored to {precision.keepbits} mantissa bits"
        if precision is not None and precision.along is not None:
            stored += f" of each peak along {precision.along}"
        return f"`{spec.name}` ({', '.join(spec.dims)}) {spec.describe_dtype()}{units}{stored}"

    for schema in schemas if schemas is not None else GROUP_SCHEMAS.values():
        variables = "<br>".join(fmt(s) for s in schema.variables)
        if schema.optional_variables:
            variables += "<br>optional: " + "<br>".join(fmt(s) for s in schema.optional_variables)
        coords = "<br>".join(fmt(s) for s in schema.coords) or "-"
        attrs = ", ".join(f"`{k}`" for k in schema.attrs) or "-"
        rows.append(f"| `{schema.name}` | {schema.description} | {variables} | {coords} | {attrs} |")
    return "\n".join(rows)
