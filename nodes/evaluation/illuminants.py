"""The illuminants of the CIEDE2000 colour difference, by name, known without colour-science.

The ``evaluate`` node offers every key of ``colour.SDS_ILLUMINANTS`` as a choice. Importing
colour-science is slow (it imports matplotlib), which declaring the node (``spectralize
nodes``) must not pay, so the names are written out here and the distributions loaded from
colour-science on first access; a test (tests/flows/test_cli_fast.py) checks the names
against the installed colour-science.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import colour

__all__ = ["ILLUMINANT_NAMES", "ILLUMINANTS"]


#: The keys of ``colour.SDS_ILLUMINANTS`` (colour-science 0.4.7) plus ``"E"``, written out so
#: that the ``evaluate`` node's choices are known without importing colour-science; a test
#: (tests/flows/test_cli_fast.py) checks them against the installed colour-science.
ILLUMINANT_NAMES: tuple[str, ...] = (
    "A", "B", "C", "D50", "D55", "D60", "D65", "D75", "E",
    "FL1", "FL2", "FL3", "FL4", "FL5", "FL6", "FL7", "FL8", "FL9", "FL10", "FL11", "FL12",
    "FL3.1", "FL3.2", "FL3.3", "FL3.4", "FL3.5", "FL3.6", "FL3.7", "FL3.8", "FL3.9", "FL3.10",
    "FL3.11", "FL3.12", "FL3.13", "FL3.14", "FL3.15",
    "HP1", "HP2", "HP3", "HP4", "HP5",
    "LED-B1", "LED-B2", "LED-B3", "LED-B4", "LED-B5", "LED-BH1", "LED-RGB1", "LED-V1", "LED-V2",
    "ID65", "ID50",
    "ISO 7589 Photographic Daylight", "ISO 7589 Sensitometric Daylight", "ISO 7589 Studio Tungsten",
    "ISO 7589 Sensitometric Studio Tungsten", "ISO 7589 Photoflood",
    "ISO 7589 Sensitometric Photoflood", "ISO 7589 Sensitometric Printer",
)  # fmt: skip


class _IlluminantTable(Mapping[str, "colour.SpectralDistribution | None"]):
    """:data:`ILLUMINANTS`: the names without colour-science, the distributions on first use."""

    def __init__(self, names: Sequence[str]) -> None:
        self._names = tuple(names)
        self._table: dict[str, colour.SpectralDistribution | None] | None = None

    def __contains__(self, name: object) -> bool:
        return name in self._names

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)

    def __getitem__(self, name: str) -> colour.SpectralDistribution | None:
        if name not in self._names:
            raise KeyError(name)
        if self._table is None:
            import colour

            self._table = {"E": None, **colour.SDS_ILLUMINANTS}
        return self._table[name]


#: Illuminants of the CIEDE2000 colour difference by name: colour-science's table plus
#: ``"E"`` (equal energy: the cubes are integrated as they are). The distributions are
#: loaded from colour-science on first access.
ILLUMINANTS: Mapping[str, colour.SpectralDistribution | None] = _IlluminantTable(ILLUMINANT_NAMES)
