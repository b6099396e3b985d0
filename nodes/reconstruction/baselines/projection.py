"""Per-pixel projection of spectra onto the RGB constraint ``C S(p) = R(p)`` (eq. 1, second term).

Shared by the baselines that end in the RGB-consistent subspace (``"filtered-projected"``,
``"guided-projected"``).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, eq. 1.
"""

from __future__ import annotations

import numpy as np

from spectralize.schemas.errors import ReconstructionError

__all__ = ["project_onto_rgb"]


def project_onto_rgb(
    cube: np.ndarray, camera_matrix: np.ndarray, rgb: np.ndarray, *, overwrite: bool = False
) -> np.ndarray:
    """Smallest per-pixel change of ``cube`` that makes ``C S(p) = R(p)`` exact.

    ``S = B + C^T (C C^T)^-1 (R - C B)``, computed in chunks of pixels (the temporaries are
    one chunk's).

    Parameters
    ----------
    cube
        ``(n_wavelength, ...)`` spectra ``B``.
    camera_matrix
        ``C``, ``(3, n_wavelength)``; or one ``C_m`` per image ``(n_image, 3,
        n_wavelength)``, then ``cube`` is ``(n_wavelength, n_image, ...)``.
    rgb
        ``R``, ``(3, ...)`` with the same trailing shape as ``cube``.
    overwrite
        Project ``cube`` in place (a C-contiguous floating array) instead of a copy.

    Returns
    -------
    numpy.ndarray
        Shaped like ``cube``.
    """
    out = cube if overwrite else np.array(cube, dtype=np.result_type(cube, np.float32))
    n_wavelength = out.shape[0]
    c = np.asarray(camera_matrix, dtype=np.float64)
    if c.ndim == 2:
        _project(out.reshape(n_wavelength, -1), rgb.reshape(3, -1), c)
        return out
    n_image = c.shape[0]
    if out.ndim < 2 or out.shape[1] != n_image:
        raise ReconstructionError(
            f"cube: expected (n_wavelength, n_image={n_image}, ...) for a camera_matrix per "
            f"image, found shape {out.shape}"
        )
    per_image = out.reshape(n_wavelength, n_image, -1)  # a view: ``out`` is C-contiguous
    targets = rgb.reshape(3, n_image, -1)
    for m in range(n_image):
        _project(per_image[:, m], targets[:, m], c[m])
    return out


def _project(flat: np.ndarray, targets: np.ndarray, c: np.ndarray) -> None:
    """``flat`` ``(n_wavelength, n)`` projected onto ``c flat = targets`` in place."""
    pseudo = c.T @ np.linalg.inv(c @ c.T)  # (n_wavelength, 3)
    for start in range(0, flat.shape[1], _CHUNK):
        here = slice(start, start + _CHUNK)
        gap = targets[:, here] - c @ flat[:, here]
        flat[:, here] += (pseudo @ gap).astype(flat.dtype, copy=False)


_CHUNK = 1 << 16
