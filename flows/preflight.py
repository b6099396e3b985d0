"""The value checks a flow's nodes make before computing, run on a store without the flow.

``spectralize validate STORE --flow F`` must not pass a store that ``F`` then rejects. The
contract's own value rules (NaN/inf, ranges) are :meth:`RunStore.validate`'s; the rules below
are those the calibration nodes apply to their exposure series before any numerics
(:mod:`spectralize.nodes.calibration.exposure_series`: exposure times positive, finite and
strictly increasing; values within the bit depth; no frame entirely saturated). They are the
nodes' own functions, called with the nodes' default thresholds, so one rule set decides both.

References
----------
Fast Capture of Spectral Image Series, sec. 4 (the exposure series of the calibration).
"""

from __future__ import annotations

from collections.abc import Callable

import xarray as xr

from spectralize.schemas import Problem, SpectralizeError
from spectralize.store import RunStore

__all__ = ["NODE_CHECKS", "flow_value_problems"]


def _problems(check: Callable[[], None], where: str) -> list[Problem]:
    """What a node's check raises, as problems (nothing when it passes)."""
    try:
        check()
    except SpectralizeError as error:
        listed = [p for p in error.problems if isinstance(p, Problem)]
        found = error.summary.removeprefix(f"{where}: ")
        return listed or [Problem(where, "an exposure series the node accepts", found)]
    return []


def _times(ds: xr.Dataset, node: str, group: str, name: str, dim: str) -> list[Problem]:
    from spectralize.nodes.calibration.exposure_series import check_exposure_times

    if name not in ds.coords and name not in ds:
        return []
    times = ds[name].transpose(..., dim)
    where = f"{node}: {group}"
    return _problems(lambda: check_exposure_times(times, dim, where), where)


def _rgb_series(ds: xr.Dataset, node: str) -> list[Problem]:
    """``recover_rgb_oecf`` and ``hdr_merge``: raw/rgb's series, and no frame entirely saturated."""
    from spectralize.nodes.calibration.exposure_series import check_bit_depth, check_frames

    problems = _times(ds, node, "raw/rgb", "exposure_time", "exposure")
    counts = ds["counts"]
    bits = ds.attrs.get("bit_depth", counts.attrs.get("bit_depth"))
    where = f"{node}: raw/rgb:counts"
    depth = _problems(lambda: check_bit_depth(bits, where="raw/rgb.attrs['bit_depth']"), where)
    if depth:
        return problems + depth
    top = 2 ** int(bits) - 1
    return problems + _problems(
        lambda: check_frames(
            counts,
            ("image", "exposure", "channel"),
            black_level=-1,  # the entirely-dark rule needs the node's data-driven black level
            saturation=top,
            max_code=top,
            where=where,
            times=ds["exposure_time"],
        ),
        where,
    )


def _target_series(ds: xr.Dataset, node: str, group: str) -> list[Problem]:
    """The white reference's and colour checker's RGB and band exposure series."""
    return _times(ds, node, group, "rgb_exposure_time", "rgb_exposure") + _times(
        ds, node, group, "spectral_exposure_time", "spectral_exposure"
    )


NODE_CHECKS: dict[str, dict[str, Callable[[xr.Dataset, str], list[Problem]]]] = {
    "recover_rgb_oecf": {"raw/rgb": _rgb_series},
    "hdr_merge": {"raw/rgb": _rgb_series},
    "recover_spectral_oecf": {
        "raw/white_reference": lambda ds, node: _times(
            ds, node, "raw/white_reference", "spectral_exposure_time", "spectral_exposure"
        )
    },
    "calibrate_spectral": {
        "raw/white_reference": lambda ds, node: _target_series(ds, node, "raw/white_reference"),
        "raw/colour_checker": lambda ds, node: _target_series(ds, node, "raw/colour_checker"),
    },
}
"""node -> {input group -> its checks}: what each calibration node refuses before computing."""


def flow_value_problems(store: RunStore, flow: str) -> list[Problem]:
    """The problems the nodes of ``flow`` would raise before computing, for the groups present.

    Each group is read once (its frames reduced with dask); a group checked for several nodes
    reports a problem once.
    """
    from spectralize.flows.pipelines import get_flow

    problems: list[Problem] = []
    seen: set[str] = set()
    for step in get_flow(flow).steps:
        for group, check in NODE_CHECKS.get(step.node, {}).items():
            if not store.has(group):
                continue  # a missing group is validate's own problem (``required``)
            for problem in check(store.read(group, friendly=False), step.node):
                text = str(problem).split(": ", 1)[-1]
                if text not in seen:
                    seen.add(text)
                    problems.append(problem)
    return problems
