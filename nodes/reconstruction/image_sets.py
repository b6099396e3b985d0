"""Image-set selection for multi-image reconstruction (paper sec. 4, 5).

The paper reconstructs a run in sets of 20 images: the 10 images at the spectral camera's
45 degree elevation whose LEDs have band shots (all 32 bands spread over them), plus 10
images from other elevations with the most similar light directions, which get their spectra
through the appearance-neighbourhood term alone.

Here the images with band shots (*anchors*) are grouped in acquisition order into anchor
groups that together hold every band of the run (one sweep of the tunable filter: the
paper's 10 LED positions), or into groups of a fixed ``anchors_per_set``. Every
other image joins the anchor group whose mean light direction is closest to its own; each
anchor group's others are split, most similar first, into chunks of ``others_per_set``, and
each chunk plus the group's anchors makes one set. Every image is *owned* by exactly one set
(anchors by their group's first set), so the spectra cube holds each image once; anchors also
take part, unowned, in their group's later sets.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 4 and 5.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
import xarray as xr
from pydantic import Field

from spectralize.schemas import SchemaError
from spectralize.schemas.errors import Problem

__all__ = ["light_direction", "select_image_sets", "set_members"]


def light_direction(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit vectors (..., 3) of directions given by polar ``theta`` and azimuth ``phi`` [degree]."""
    t, p = np.deg2rad(np.asarray(theta, float)), np.deg2rad(np.asarray(phi, float))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def _sweeps(
    anchors: list[int], labels: np.ndarray, shot_images: np.ndarray, shot_wavelengths: np.ndarray
) -> list[list[int]]:
    """Consecutive anchors grouped until each group has a shot of every wavelength."""
    every = set(np.round(shot_wavelengths, 3).tolist())
    groups: list[list[int]] = [[]]
    seen: set[float] = set()
    for index in anchors:
        groups[-1].append(index)
        seen |= set(np.round(shot_wavelengths[shot_images == labels[index]], 3).tolist())
        if seen >= every:
            groups.append([])
            seen = set()
    if not groups[-1]:
        groups.pop()
    elif len(groups) > 1:  # an incomplete last sweep joins the one before it
        groups[-2].extend(groups.pop())
    return groups


def select_image_sets(
    images: xr.Dataset,
    shots: xr.Dataset,
    *,
    anchors_per_set: Annotated[
        int | None,
        Field(ge=1, description="images with band shots per set; None: one sweep of all bands"),
    ] = None,
    others_per_set: Annotated[int, Field(ge=0)] = 10,
) -> xr.Dataset:
    """Split a run's images into reconstruction sets.

    Parameters
    ----------
    images
        Any group with per-image coords (``raw/rgb`` or ``hdr``): ``image``, ``theta_i``,
        ``phi_i``.
    shots
        Any group with per-shot coord ``image`` (``raw/spectral`` or ``bands``).
    anchors_per_set
        Images with band shots per set; ``None``: consecutive anchors until every band of the
        run is in the set (one sweep of the filter; 10 in the paper), so that every set has
        every band.
    others_per_set
        Images without band shots per set (10 in the paper).

    Returns
    -------
    xarray.Dataset
        Group ``image_sets``: ``image_set`` (image) owning set; ``member`` (set, slot) image
        labels of each set's members, anchors first, -1 padded; ``owned`` (set, slot) whether
        the member is owned by that set; ``has_bands`` (image); ``light_distance`` (image)
        [degree] to the mean light direction of the image's anchor group. Attr ``seed_set``:
        the set solved first to warm-start the others.

    Raises
    ------
    SchemaError
        Missing coords, or no shot pairs with any image.
    """
    problems = [
        Problem(f"images:{c}", "a per-image coordinate", "nothing")
        for c in ("image", "theta_i", "phi_i")
        if c not in images.coords
    ]
    if "image" not in shots.coords:
        problems.append(Problem("shots:image", "a per-shot coordinate", "nothing"))
    if problems:
        raise SchemaError("cannot select image sets:", problems)
    labels = images["image"].values
    shot_images = shots["image"].values
    has_bands = np.isin(labels, shot_images)
    if not has_bands.any():
        raise SchemaError(
            "cannot select image sets:",
            [
                Problem(
                    "shots:image",
                    f"labels of images in {labels.min()}..{labels.max()}",
                    f"{np.unique(shot_images).tolist()[:10]} (no shot pairs with an image)",
                )
            ],
        )
    directions = light_direction(images["theta_i"].values, images["phi_i"].values)

    # anchors in acquisition order (order of their first shot)
    first_shot: dict[int, int] = {}
    for index, label in enumerate(shot_images):
        first_shot.setdefault(int(label), index)
    anchors = sorted(
        (int(i) for i in np.flatnonzero(has_bands)), key=lambda i: first_shot[int(labels[i])]
    )
    if anchors_per_set is None:
        if "wavelength" not in shots.coords:
            raise SchemaError(
                "cannot select image sets:",
                [
                    Problem(
                        "shots:wavelength", "a per-shot coordinate (or give anchors_per_set)", "nothing"
                    )
                ],
            )
        groups = _sweeps(anchors, labels, shot_images, np.asarray(shots["wavelength"].values))
    else:
        groups = [anchors[k : k + anchors_per_set] for k in range(0, len(anchors), anchors_per_set)]
    centres = np.stack([directions[g].mean(axis=0) for g in groups])
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)

    others = np.flatnonzero(~has_bands)
    cosines = np.clip(directions[others] @ centres.T, -1.0, 1.0)
    nearest = np.argmax(cosines, axis=1) if others.size else np.array([], int)
    distance = np.zeros(labels.size)
    for g, members in enumerate(groups):
        distance[members] = np.degrees(np.arccos(np.clip(directions[members] @ centres[g], -1, 1)))
    distance[others] = np.degrees(np.arccos(cosines[np.arange(others.size), nearest]))

    sets: list[tuple[list[int], list[bool]]] = []  # (member indices, owned flags)
    for g, members in enumerate(groups):
        mine = others[nearest == g]
        mine = mine[np.argsort(distance[mine], kind="stable")]
        chunks = (
            [mine[k : k + others_per_set] for k in range(0, mine.size, others_per_set)]
            if others_per_set > 0
            else []
        )
        if others_per_set == 0 and mine.size:
            raise SchemaError(
                "cannot select image sets:",
                [
                    Problem(
                        "others_per_set",
                        "at least 1 when images without band shots exist",
                        f"0 with {others.size} such images",
                    )
                ],
            )
        chunks = chunks or [np.array([], int)]
        for c, chunk in enumerate(chunks):
            member = list(members) + chunk.tolist()
            owned = [c == 0] * len(members) + [True] * chunk.size
            sets.append((member, owned))

    member, owned_table, image_set = _set_table(sets, labels)
    # the seed: the set whose anchor group is most central in light direction
    overall = directions.mean(axis=0)
    seed = int(np.argmax([centres[_group_of(s, sets, groups)] @ overall for s in range(len(sets))]))
    return xr.Dataset(
        {
            "image_set": ("image", image_set, {"long_name": "set that owns the image"}),
            "has_bands": ("image", has_bands, {"long_name": "image has band shots"}),
            "light_distance": (
                "image",
                distance.astype(np.float32),
                {
                    "units": "degree",
                    "long_name": "angle to the mean light direction of the image's anchor group",
                },
            ),
            "member": (
                ("set", "slot"),
                member,
                {"long_name": "image labels of the members, anchors first, -1: none"},
            ),
            "owned": (("set", "slot"), owned_table, {"long_name": "member is owned by the set"}),
        },
        coords={"image": ("image", labels), "set": ("set", np.arange(len(sets)))},
        attrs={
            "seed_set": seed,
            "anchors_per_set": anchors_per_set or "one sweep",
            "others_per_set": others_per_set,
            "anchor_groups": len(groups),
        },
    )


def _set_table(
    sets: list[tuple[list[int], list[bool]]], labels: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sets ``(member indices, owned flags)`` as the group's arrays: ``member`` (set,
    slot) image labels padded with -1, ``owned`` (set, slot) and ``image_set`` (image), the
    set that owns each image."""
    width = max(len(m) for m, _ in sets)
    member = np.full((len(sets), width), -1, dtype=np.int64)
    owned = np.zeros((len(sets), width), dtype=bool)
    image_set = np.full(labels.size, -1, dtype=np.int64)
    for s, (indices, flags) in enumerate(sets):
        member[s, : len(indices)] = labels[indices]
        owned[s, : len(indices)] = flags
        for i, flag in zip(indices, flags, strict=True):
            if flag:
                image_set[i] = s
    return member, owned, image_set


def _group_of(s: int, sets, groups) -> int:
    first = sets[s][0][0]
    return next(g for g, members in enumerate(groups) if first in members)


def set_members(image_sets: xr.Dataset, index: int) -> tuple[np.ndarray, np.ndarray]:
    """Image labels of set ``index`` and whether each is owned by it.

    Parameters
    ----------
    image_sets
        Group ``image_sets`` (:func:`select_image_sets`).
    index
        Position of the set along ``set``.

    Returns
    -------
    tuple of numpy.ndarray
        ``(labels, owned)``, anchors first, without the padding.
    """
    member = image_sets["member"].isel(set=index).values
    owned = image_sets["owned"].isel(set=index).values
    keep = member >= 0
    return member[keep], owned[keep]
