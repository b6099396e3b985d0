"""Weights of the three terms of eq. 1 (eq. 4).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Optimization", eq. 4.
"""

from __future__ import annotations

from dataclasses import dataclass

from spectralize.schemas.errors import ReconstructionError

__all__ = ["TermWeights", "term_weights", "default_gamma_hat"]


@dataclass(frozen=True)
class TermWeights:
    """``alpha``, ``beta``, ``gamma`` of eq. 1 and the counts they come from (eq. 4)."""

    alpha: float
    beta: float
    gamma: float
    n_filters: int
    n_pixels: int
    n_neighbour_pairs: int

    @property
    def n_equations(self) -> int:
        """``M = K + 3P + sum_p |N_p|``."""
        return self.n_filters + 3 * self.n_pixels + self.n_neighbour_pairs


def default_gamma_hat(n_images: int) -> float:
    """The paper's ``gamma_hat``: 1 for a single image, 20 for a multi-image set.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, "Optimization", and section 5.
    """
    return 1.0 if n_images <= 1 else 20.0


def term_weights(
    n_filters: int,
    n_pixels: int,
    n_neighbour_pairs: int,
    *,
    alpha_hat: float = 1.0,
    beta_hat: float = 1.0,
    gamma_hat: float = 1.0,
) -> TermWeights:
    """Eq. 4: weight each term by the share of equations it contributes.

    ``M = K + 3P + sum_p |N_p|``, ``alpha = alpha_hat M / K``, ``beta = beta_hat M / (3P)``,
    ``gamma = gamma_hat M / sum_p |N_p|``.

    Parameters
    ----------
    n_filters
        ``K``, the number of filter constraints (filter centres over all band shots).
    n_pixels
        ``P``, all pixels of all images of the set.
    n_neighbour_pairs
        ``sum_p |N_p|`` (``k P`` for ``k`` neighbours per pixel).
    alpha_hat, beta_hat, gamma_hat
        The user's relative weights (paper: 1, 1 and 1 for one image or 20 for a set).

    Returns
    -------
    TermWeights
        A term without equations gets weight 0.

    Raises
    ------
    ReconstructionError
        (a ``ValueError``) for negative counts or weights, or when there are no equations at all.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 4.
    """
    counts = {"n_filters": n_filters, "n_pixels": n_pixels, "n_neighbour_pairs": n_neighbour_pairs}
    hats = {"alpha_hat": alpha_hat, "beta_hat": beta_hat, "gamma_hat": gamma_hat}
    for name, value in {**counts, **hats}.items():
        if not value >= 0:
            raise ReconstructionError(f"{name}: expected a number >= 0, found {value!r}")
    total = n_filters + 3 * n_pixels + n_neighbour_pairs
    if total == 0:
        raise ReconstructionError("eq. 4 needs at least one equation: K, P and sum |N_p| are all 0")

    def share(hat: float, count: int) -> float:
        return float(hat) * total / count if count else 0.0

    return TermWeights(
        share(alpha_hat, n_filters),
        share(beta_hat, 3 * n_pixels),
        share(gamma_hat, n_neighbour_pairs),
        int(n_filters),
        int(n_pixels),
        int(n_neighbour_pairs),
    )
