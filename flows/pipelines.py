"""The named flows a user runs with ``spectralize run FLOW STORE``.

A flow is a list of steps; the engine orders and checks them. Keep them declarative.
"""

from __future__ import annotations

from dataclasses import dataclass

from spectralize.engine import Step
from spectralize.schemas import SpectralizeError

__all__ = ["FlowDefinition", "FLOWS", "get_flow"]


@dataclass(frozen=True)
class FlowDefinition:
    """A named graph of node steps."""

    name: str
    description: str
    steps: tuple[Step, ...]
    report: bool = False  # write the HTML report when the run has an evaluation


#: The full-BTF processing of a raw run store, in paper order.
BTF_STEPS: tuple[Step, ...] = (
    Step("dark_average"),
    Step("recover_rgb_oecf"),
    Step("recover_spectral_oecf"),
    Step("calibrate_spectral"),
    Step("hdr_merge"),
    Step("estimate_registration"),
    Step("calibrate_bands"),
    Step("select_image_sets"),
    Step("reconstruct_seed_set", inputs={"calibration": "calibration/spectral"}),
    Step("reconstruct_image_sets", inputs={"calibration": "calibration/spectral"}),
    # simulated runs only: evaluation against ground truth (left out without truth/spectra)
    Step("evaluate", optional=True),
)

FLOWS: dict[str, FlowDefinition] = {
    flow.name: flow
    for flow in (
        FlowDefinition(
            name="dark",
            description="dark-frame averaging: raw/dark -> dark",
            steps=(Step("dark_average"),),
        ),
        FlowDefinition(
            name="calibrate",
            description="radiometric calibration (sec. 4): dark -> OECFs -> QE, C and cross-validation",
            steps=(
                Step("dark_average"),
                Step("recover_rgb_oecf"),
                Step("recover_spectral_oecf"),
                Step("calibrate_spectral"),
            ),
        ),
        FlowDefinition(
            name="btf",
            description="full-BTF processing of a raw run store",
            steps=BTF_STEPS,
            report=True,
        ),
        FlowDefinition(
            name="demo",
            description="simulate the bundled sample run (recipe 'demo'), then process it",
            steps=(Step("simulate", parameters={"recipe": "demo"}), *BTF_STEPS),
            report=True,
        ),
    )
}


def get_flow(name: str) -> FlowDefinition:
    """The flow called ``name``, or a one-step flow running the installed node ``name``.

    Raises
    ------
    SpectralizeError
        Listing the known flows and nodes.
    """
    from spectralize.engine import registry

    if name in FLOWS:
        return FLOWS[name]
    nodes = registry()
    if name in nodes:
        return FlowDefinition(name, f"the single node {name}", (Step(name),))
    raise SpectralizeError(
        f"unknown flow or node {name!r}; flows: {', '.join(sorted(FLOWS))}; "
        f"nodes: {', '.join(sorted(nodes)) or 'none'}"
    )
