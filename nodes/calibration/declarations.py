"""Declarations of the calibration nodes (paper section 4): every calibration :class:`Node`.

Every calibration node is declared here, beside the science it runs; the ``pyproject.toml``
entry points name these objects. The node functions live with their method:

=========================  ===================================  ==================================
node                       function                             groups
=========================  ===================================  ==================================
``dark_average``           :func:`.dark.average_dark_frames`    raw/dark -> dark
``recover_rgb_oecf``       :func:`.oecf.robertson.              raw/rgb, raw/colour_checker,
                           recover_rgb_oecf`                    raw/white_reference
                                                                -> calibration/oecf_rgb
``recover_spectral_oecf``  :func:`.oecf.low_snr.                raw/white_reference, dark
                           recover_spectral_oecf`               -> calibration/oecf_spectral
``calibrate_spectral``     :func:`.spectral.                    raw/white_reference,
                           calibrate_spectral`                  raw/colour_checker, dark,
                                                                calibration/oecf_rgb,
                                                                calibration/oecf_spectral
                                                                -> calibration/spectral
``hdr_merge``              :func:`merge_hdr_node` (wiring to    raw/rgb, calibration/oecf_rgb,
                           :func:`.hdr.merge_hdr`)              raw/white_reference -> hdr
``estimate_registration``  :func:`.registration.                raw/registration -> registration
                           estimate_registration`
``calibrate_bands``        :func:`.band_radiance.               raw/spectral, dark,
                           calibrate_bands`                     calibration/oecf_spectral,
                                                                calibration/spectral,
                                                                registration -> bands
=========================  ===================================  ==================================

The engine checks every input group against the schema its node declares
(:data:`spectralize.schemas.run.GROUP_SCHEMAS`) before calling the function, so the functions
check only what a schema cannot say (bit depths in range, exposure times present in the dark
frames, saturation). The nodes that read exposure series declare those checks as their value
check (``check=``, the ``*_check`` functions below): the engine runs it before the function,
and ``spectralize validate --flow`` runs it on a store, with the same functions the node
functions raise from. Parameters are the functions' keyword-only arguments: the engine derives
each node's frozen parameter model from the annotations (``Annotated[T, Field(...)]``, and
``Choices(WEIGHTING_FUNCTIONS)`` for the weighting), so types, defaults and limits are
written once.

Units: the RGB response is normalised to 1 at its mid code, so HDR radiance is "relative
exposure per second". The spectral response is scaled onto its own full-range Robertson
response, and ``Q`` divides the white reference's band signal by its reflectance times the
*measured illuminant*: band radiance is therefore relative to the measured illuminant (a white
diffuser of reflectance 1 under it has band radiance ``L(lambda)``). ``C`` is fitted from the
colour checker's HDR RGB against patch reflectance times the same illuminant, so it maps band
radiance units to HDR units, which is what the reconstruction needs (``RGB = C @ spectrum``).
``calibration/spectral`` carries that ``L`` on the band wavelengths (``illuminant``, units
``"1"``), the illuminant the set model ``"shared-texel"`` of the reconstruction needs.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated

import numpy as np
import xarray as xr
from pydantic import Field

from spectralize.engine import Node, Parameters
from spectralize.nodes.calibration.band_radiance import calibrate_bands
from spectralize.nodes.calibration.dark import average_dark_frames
from spectralize.nodes.calibration.exposure_series import target_series_refusals
from spectralize.nodes.calibration.flat_field import camera_flat_fields
from spectralize.nodes.calibration.hdr import merge_hdr, merge_hdr_refusals
from spectralize.nodes.calibration.oecf.low_snr import recover_spectral_oecf, spectral_oecf_refusals
from spectralize.nodes.calibration.oecf.robertson import recover_rgb_oecf, rgb_oecf_refusals
from spectralize.nodes.calibration.registration import estimate_registration
from spectralize.nodes.calibration.spectral import calibrate_spectral
from spectralize.schemas import SpectralizeError

__all__ = [
    "merge_hdr_node",
    "rgb_oecf_check",
    "hdr_merge_check",
    "spectral_oecf_check",
    "calibrate_spectral_check",
    "DARK_AVERAGE",
    "RECOVER_RGB_OECF",
    "RECOVER_SPECTRAL_OECF",
    "CALIBRATE_SPECTRAL",
    "HDR_MERGE",
    "ESTIMATE_REGISTRATION",
    "CALIBRATE_BANDS",
]


# -- the one wiring-only node function ---------------------------------------------------
def merge_hdr_node(
    raw_rgb: xr.Dataset,
    oecf_rgb: xr.Dataset,
    white_reference: xr.Dataset | None = None,
    *,
    black_level: Annotated[
        int | None,
        Field(
            ge=0,
            description="under-exposed codes [DN], for every camera; None: each camera's own "
            "(calibration/oecf_rgb's black_level)",
        ),
    ] = None,
    saturation: Annotated[
        int | None,
        Field(ge=1, description="saturated codes [DN], for every camera; None: the response's"),
    ] = None,
) -> xr.Dataset:
    """HDR RGB radiance of every raw/rgb image (Robertson's estimator), lazy per chunk.

    Wires the groups to :func:`~spectralize.nodes.calibration.hdr.merge_hdr`: each image's
    codes are weighted with its own camera's levels, ``calibration/oecf_rgb``'s
    ``black_level`` (camera) [DN] and ``saturation``, and the group's ``weighting``, unless
    ``black_level``/``saturation`` are given here (then for every camera). With
    ``white_reference`` (group ``raw/white_reference``) each image is divided by its camera's
    flat field (:func:`~spectralize.nodes.calibration.flat_field.camera_flat_fields`, the
    maps ``calibrate_spectral`` stores and fits ``C`` through).

    Returns
    -------
    xarray.Dataset
        Group ``hdr``: ``radiance`` (image, y, x, channel) float32 [1] and the per-image
        coords of raw/rgb.
    """
    flat = None
    if white_reference is not None:
        cameras = sorted({int(c) for c in np.asarray(raw_rgb["camera"].values).tolist()})
        flat = camera_flat_fields(white_reference, oecf_rgb, cameras)
    out = merge_hdr(raw_rgb, oecf_rgb, black_level=black_level, saturation=saturation, flat_field=flat)
    out["radiance"] = (
        out["radiance"].astype(np.float32).assign_attrs(units="1", long_name="relative RGB radiance")
    )
    return out


# -- value checks (Node.check): what each node refuses before computing ---------------------
def rgb_oecf_check(inputs: Mapping[str, xr.Dataset], parameters: Parameters) -> list[SpectralizeError]:
    """``recover_rgb_oecf``: raw/rgb's series, with the black level the node would use and each
    camera's white level as the node finds it (declared, else in the longest exposures of
    raw/rgb and the calibration targets)."""
    if "raw_rgb" not in inputs:
        return []
    targets = [inputs[name] for name in ("colour_checker", "white_reference") if name in inputs]
    return rgb_oecf_refusals(
        inputs["raw_rgb"], black_level=parameters.model_dump()["black_level"], targets=targets
    )


def hdr_merge_check(inputs: Mapping[str, xr.Dataset], parameters: Parameters) -> list[SpectralizeError]:
    """``hdr_merge``: raw/rgb's series, with the levels :func:`merge_hdr_node` would use (each
    image's camera's, from calibration/oecf_rgb, unless the parameters set them)."""
    if "raw_rgb" not in inputs:
        return []
    values = parameters.model_dump()
    return merge_hdr_refusals(
        inputs["raw_rgb"],
        black_level=values["black_level"],
        saturation=values["saturation"],
        response=inputs.get("oecf_rgb"),  # before the response is made, the dark rule waits
    )


def spectral_oecf_check(
    inputs: Mapping[str, xr.Dataset], parameters: Parameters
) -> list[SpectralizeError]:
    """``recover_spectral_oecf``: the white reference's band series."""
    if "white_reference" not in inputs:
        return []
    return spectral_oecf_refusals(inputs["white_reference"])


def calibrate_spectral_check(
    inputs: Mapping[str, xr.Dataset], parameters: Parameters
) -> list[SpectralizeError]:
    """``calibrate_spectral``: the targets' RGB and band series' exposure times."""
    found: list[SpectralizeError] = []
    for argument, group in (
        ("white_reference", "raw/white_reference"),
        ("colour_checker", "raw/colour_checker"),
    ):
        if argument in inputs:
            found += target_series_refusals(inputs[argument], group, "calibrate_spectral")
    return found


# -- nodes --------------------------------------------------------------------------------
DARK_AVERAGE = Node(
    name="dark_average",
    version="2",  # 2: per pixel a line in exposure time through all frames (model="linear")
    function=average_dark_frames,
    inputs={"raw_dark": "raw/dark"},
    outputs=("dark",),
    description="Average raw dark frames per exposure time into float32 mean and std (sec. 4).",
)

RECOVER_RGB_OECF = Node(
    name="recover_rgb_oecf",
    # 2: one response per camera by default, each camera's own black level, and its series of
    # the calibration targets with its raw/rgb series; 3: the response a cubic spline of
    # SMOOTH_RGB coefficients (Robertson's solution over that space); 4: the black level per
    # camera as a variable (black_level over camera, DN) for the HDR merge, and the series read
    # once, at most MAX_IMAGES images per camera (a deterministic spread); 5: each camera's
    # white level (declared, else found in its longest exposures) and the saturation under it
    # (white_level, saturation over camera), which the fit, the targets' series and the HDR
    # merge use; 6: the white level found in each source's longest exposures apart (the
    # scene's, each target's), and frames entirely at or above it refused before computing;
    # 7: the codes under the low end's anchor from the reverse regression (low_end); 8: each
    # channel's response smoothed to a spline in the log code of the coefficients its series
    # chooses (log_spline)
    version="8",
    function=recover_rgb_oecf,
    inputs={
        "raw_rgb": "raw/rgb",
        "colour_checker": "raw/colour_checker",
        "white_reference": "raw/white_reference",
    },
    outputs=("calibration/oecf_rgb",),
    check=rgb_oecf_check,
    description="RGB camera response per channel by Robertson 2003 from raw/rgb (sec. 4).",
)

RECOVER_SPECTRAL_OECF = Node(
    name="recover_spectral_oecf",
    version="1",
    function=recover_spectral_oecf,
    inputs={"white_reference": "raw/white_reference", "dark": "dark"},
    outputs=("calibration/oecf_spectral",),
    check=spectral_oecf_check,
    description="Spectral camera response: low-SNR extension joined to Robertson (sec. 4).",
)

CALIBRATE_SPECTRAL = Node(
    name="calibrate_spectral",
    version="11",  # 3: C, its map onto the paired camera and the cross-check per RGB camera;
    # 4: C held to zero where the targets had little light (weak_light); 5: the measured
    # illuminant L on the band wavelengths (illuminant), which set_model 'shared-texel' reads;
    # 6: the targets' RGB series saturated at each camera's saturation (calibration/oecf_rgb);
    # 7: every camera's flat field from the white reference (flat_field_rgb, flat_field), the
    # targets divided by it before Q and C are fitted; 8: one RGB flat field per camera (the
    # mean of its channels' maps); 9: the RGB flat field through the white reference's own
    # smooth response, fitted jointly with it (flat_field_response); 10: each band's flat
    # field through one smooth spectral response fitted on the band series by the exposures'
    # ratios (band_series_response), not the recovered spectral OECF; 11: the bands' flat
    # fields smoothed across wavelength, weighted by their noise floors (smooth_across_bands)
    function=calibrate_spectral,
    inputs={
        "white_reference": "raw/white_reference",
        "colour_checker": "raw/colour_checker",
        "dark": "dark",
        "oecf_rgb": "calibration/oecf_rgb",
        "oecf_spectral": "calibration/oecf_spectral",
    },
    outputs=("calibration/spectral",),
    check=calibrate_spectral_check,
    description="Quantum efficiency, camera matrix C and cross-validation (sec. 4, Fig. 4).",
)

HDR_MERGE = Node(
    name="hdr_merge",
    # 2: each image's codes weighted with its own camera's black level (calibration/oecf_rgb's
    # black_level over camera), not the lowest camera's for all; 3: each image divided by its
    # camera's flat field from the white reference (raw/white_reference); 4: one flat field per
    # camera (the mean of its channels' maps); 5: the flat field through the white
    # reference's own smooth response (flat_field_response)
    version="5",
    function=merge_hdr_node,
    inputs={
        "raw_rgb": "raw/rgb",
        "oecf_rgb": "calibration/oecf_rgb",
        "white_reference": "raw/white_reference",
    },
    outputs=("hdr",),
    read_by_shard=("raw_rgb",),  # every image, streamed: a task per shard
    check=hdr_merge_check,
    description="HDR RGB radiance from the exposure series (Robertson), lazy per chunk.",
)

CALIBRATE_BANDS = Node(
    name="calibrate_bands",
    version="4",  # 3: shots scaled to their paired RGB image's LED power (led_power.csv);
    # 4: each shot divided by its band's flat field (calibration/spectral flat_field)
    function=calibrate_bands,
    inputs={
        "raw_spectral": "raw/spectral",
        "dark": "dark",
        "oecf_spectral": "calibration/oecf_spectral",
        "spectral": "calibration/spectral",
        "registration": "registration",
    },
    outputs=("bands",),
    read_by_shard=("raw_spectral",),  # every shot, streamed: a task per shard
    description="Band radiance (signal / Q), registered onto the RGB grid, filter size per shot.",
)

ESTIMATE_REGISTRATION = Node(
    name="estimate_registration",
    version="2",  # 2: against the RGB channel mix that best explains the band (not the sum)
    function=estimate_registration,
    inputs={"registration": "raw/registration"},
    outputs=("registration",),
    description="Sub-pixel misregistration of the spectral camera from long-exposure shots.",
)
