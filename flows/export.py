"""``spectralize export STORE OUT --format envi|netcdf``: spectral cubes for other software.

- **ENVI** (``.hdr`` + ``.img``, band sequential float32, little endian), one pair per image:
  ``OUT/<store>_<group>_image<label>.hdr``. The header carries the wavelengths in nm, band
  names, the image's BTF angles, camera, rotation and LED; readable by Spectral Python
  (``spectral.open_image``), ENVI and GDAL.
- **netCDF** (CF-1.10, netCDF4/HDF5 through h5netcdf): one file ``OUT`` (a folder, or a
  name without suffix: ``OUT/<store>_<group>.nc``; with ``per_image``, one file per image in
  the folder ``OUT``) with ``radiance`` (image,
  wavelength, y, x) and the per-image coordinates; readable by ``xarray.open_dataset``.

Data are streamed chunk by chunk from the store: memory is bounded by one chunk (ENVI: one
band of one image), not by the run. The values are those the store keeps, in the same units:
a cube stored at a precision (``spectra``: its radiance rounded to a number of mantissa bits)
is exported as stored, with its relative bound in the radiance's attrs (netCDF
``precision_keepbits`` and ``precision_bound_relative``) or the header (ENVI
``spectralize precision bound relative``). ENVI files hold pixels without a value as
:data:`ENVI_IGNORE` (their ``data ignore value``). Radiance is relative (units ``"1"``: relative to the
measured illuminant, see the ``calibration/spectral`` group), stated in the files.
"""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from spectralize.schemas import Precision, SpectralizeError
from spectralize.store import RunStore

from .signals import sigterm_as_interrupt

__all__ = ["FORMATS", "ENVI_IGNORE", "ExportError", "export", "label_ranges", "select_images"]

FORMATS: tuple[str, ...] = ("envi", "netcdf")
_PER_IMAGE = ("camera", "rotation", "led", "theta_i", "phi_i", "theta_o", "phi_o")
#: ENVI's ``data ignore value``: pixels without a value (NaN in the store) are written as this
#: number, which every ENVI reader (Spectral Python, ENVI, GDAL) reads as a number.
ENVI_IGNORE = -9999.0
_UNITS_NOTE = (
    "relative spectral radiance (dimensionless): band radiance relative to the measured "
    "illuminant, as calibrated by spectralize (paper sec. 4)"
)


class ExportError(SpectralizeError, ValueError):
    """An export that cannot be made: unknown group, format or image labels."""


def select_images(ds: xr.Dataset, images: Sequence[int] | None) -> xr.Dataset:
    """The images with these labels (``image`` coordinate values), in the order given.

    Raises
    ------
    ExportError
        Listing labels the group does not have, and the labels it has.
    """
    labels = np.asarray(ds["image"].values) if "image" in ds.coords else np.arange(ds.sizes["image"])
    if images is None:
        return ds
    missing = [int(i) for i in images if int(i) not in set(labels.tolist())]
    if missing:
        raise ExportError.single(
            "--image",
            f"image labels of the group: {label_ranges(labels.tolist())} ({labels.size} images)",
            f"{missing}",
        )
    positions = [int(np.flatnonzero(labels == int(i))[0]) for i in images]
    return ds.isel(image=positions)


def label_ranges(labels: Sequence[int]) -> str:
    """Labels as runs: ``0-98`` or ``0-3, 7, 9-12`` (a run's hundreds of labels in a line)."""
    runs: list[list[int]] = []
    for label in sorted(set(int(v) for v in labels)):
        if runs and label == runs[-1][1] + 1:
            runs[-1][1] = label
        else:
            runs.append([label, label])
    return ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in runs) or "none"


def _cube_groups(store: RunStore) -> list[str]:
    """The finished groups holding a ``radiance`` cube (found from the files, nothing read)."""
    return [g for g in store.groups() if (store.path / g / "radiance" / "zarr.json").is_file()]


def _open(store: RunStore, group: str) -> xr.Dataset:
    if not store.has(group):
        import difflib

        cubes = _cube_groups(store)
        near = difflib.get_close_matches(group, cubes, n=1, cutoff=0.5)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        raise ExportError.single(
            "--group",
            f"a spectral-cube group of {store.path.name}: {', '.join(cubes) or 'none'}",
            group + hint,
        )
    ds = store.read(group)
    if "radiance" not in ds or set(ds["radiance"].dims) != {"image", "wavelength", "y", "x"}:
        raise ExportError.single(
            f"{group}:radiance", "a cube (image, wavelength, y, x)", f"{dict(ds.sizes)}"
        )
    return ds


def _labels(ds: xr.Dataset) -> list[int]:
    if "image" in ds.coords:
        return [int(v) for v in ds["image"].values]
    return list(range(ds.sizes["image"]))


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-")


def _envi_value(value: Any) -> str:
    if isinstance(value, list | tuple | np.ndarray):
        return "{" + ", ".join(_envi_value(v) for v in value) + "}"
    if isinstance(value, float | np.floating):
        return f"{float(value):.10g}"
    return str(value).replace("{", "(").replace("}", ")")


def _write_envi(cube: xr.DataArray, path: Path, header: dict[str, Any]) -> tuple[Path, Path]:
    """Write one image (wavelength, y, x) as ENVI BSQ float32, one band chunk at a time."""
    cube = cube.transpose("wavelength", "y", "x")
    n_bands, lines, samples = cube.shape
    image, hdr = path.with_suffix(".img"), path.with_suffix(".hdr")
    partial = image.with_name(image.name + ".partial")
    data = cube.data
    step = max(1, (data.chunks[0][0] if hasattr(data, "chunks") and data.chunks else n_bands))
    with open(partial, "wb") as out:
        for start in range(0, n_bands, step):
            block = np.asarray(cube.isel(wavelength=slice(start, start + step)).values, dtype="<f4")
            block = np.where(np.isnan(block), np.float32(ENVI_IGNORE), block)
            out.write(block.tobytes(order="C"))
    os.replace(partial, image)
    fields = {
        "description": header.pop("description"),
        "samples": samples,
        "lines": lines,
        "bands": n_bands,
        "header offset": 0,
        "file type": "ENVI Standard",
        "data type": 4,  # float32
        "interleave": "bsq",
        "byte order": 0,  # little endian
        **header,
    }
    text = "ENVI\n" + "".join(f"{key} = {_envi_value(value)}\n" for key, value in fields.items())
    hdr.write_text(text, encoding="ascii", errors="replace")
    return hdr, image


def _precision_attrs(radiance: xr.DataArray) -> dict[str, Any]:
    """The precision the store kept the cube at, as its attrs state it (none: lossless)."""
    precision = Precision.stated(radiance.attrs)
    return {} if precision is None else precision.attrs


def _netcdf_dataset(ds: xr.Dataset, store: RunStore, group: str) -> xr.Dataset:
    """A CF-1.10 dataset: radiance (and confidence) with plain attributes, no store bookkeeping."""
    keep = [v for v in ("radiance", "confidence") if v in ds.data_vars]
    out = ds[keep].copy()
    out["radiance"] = out["radiance"].transpose("image", "wavelength", "y", "x").astype(np.float32)
    out["radiance"].attrs = {
        "long_name": "relative spectral radiance",
        "units": "1",
        "comment": _UNITS_NOTE,
        **_precision_attrs(ds["radiance"]),
    }
    if "confidence" in out:
        out["confidence"].attrs = {
            "long_name": str(ds["confidence"].attrs.get("long_name", "confidence")),
            "units": str(ds["confidence"].attrs.get("units", "1")),
        }
    for dim in ("y", "x"):
        if dim not in out.coords:
            out = out.assign_coords({dim: np.arange(out.sizes[dim])})
        out[dim].attrs = {"long_name": f"pixel {'row' if dim == 'y' else 'column'}", "units": "px"}
    if "image" not in out.coords:
        out = out.assign_coords(image=np.arange(out.sizes["image"]))
    out["image"].attrs = {"long_name": "image label of the run store"}
    out["wavelength"].attrs = {
        "long_name": "wavelength",
        "standard_name": "radiation_wavelength",
        "units": "nm",
    }
    for name in _PER_IMAGE:
        if name in out.coords:
            units = "degree" if name.startswith(("theta", "phi")) else "1"
            out[name].attrs = {"long_name": str(ds[name].attrs.get("long_name", name)), "units": units}
    for name, var in out.variables.items():
        var.encoding = {}
        if var.dtype.kind == "T" or var.dtype == object:
            out[name] = var.astype(str)
    provenance = store.provenance(group) if store.has(group) else {}
    out.attrs = {
        "Conventions": "CF-1.10",
        "title": f"{group} of the run store {store.path.name}",
        "institution": "",
        "source": "spectralize (Fast Capture of Spectral Image Series)",
        "history": f"{time.strftime('%Y-%m-%dT%H:%M:%S')} spectralize export {store.path} "
        "--format netcdf",
        "references": "Fast Capture of Spectral Image Series",
        "comment": _UNITS_NOTE,
        "spectralize_group": group,
        "spectralize_fingerprint": str(store.fingerprint(group) or ""),
        "spectralize_provenance": json.dumps(provenance, default=str),
    }
    return out


def export(
    store: RunStore | str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    format: str = "netcdf",
    group: str = "spectra",
    images: Sequence[int] | None = None,
    per_image: bool = False,
    progress: Callable[[str], None] | None = None,
) -> list[Path]:
    """Export a spectral cube group of a run store as ENVI or CF netCDF files.

    Parameters
    ----------
    store
        The run store or its path.
    out
        ENVI: a folder (created). netCDF: a ``.nc`` file, or a folder with ``per_image``
        (or when ``out`` is an existing folder: ``<store>_<group>.nc`` inside it).
    format
        ``"envi"`` or ``"netcdf"``.
    group
        A group with ``radiance`` (image, wavelength, y, x): ``spectra`` (default),
        ``spectra_seed``, ``truth/spectra``.
    images
        Image labels to export (default: all).
    per_image
        netCDF: one file per image (ENVI always writes one pair per image).
    progress
        Called with a short message per file written.

    Returns
    -------
    list of pathlib.Path
        The files written (ENVI: header and image of each image).

    Raises
    ------
    ExportError
        For an unknown format, group or image label (nothing is written).

    On any failure or interruption (a damaged chunk, a full disk, Ctrl-C or SIGTERM) the
    files this call wrote, finished or partial, are removed: no half export is left behind.
    """
    written: list[Path] = []
    created: list[Path] = []
    try:
        with sigterm_as_interrupt():
            return _export(store, out, format, group, images, per_image, progress, written, created)
    except BaseException:
        _remove_output(written, created)
        raise


def _remove_output(written: list[Path], created: list[Path]) -> None:
    """Remove the files of a failed export, its ``.partial`` files and the folders it created."""
    folders = {path.parent for path in written} | set(created)
    for path in written:
        path.unlink(missing_ok=True)
        path.with_name(path.name + ".partial").unlink(missing_ok=True)
    for folder in sorted(folders, key=lambda f: len(f.parts), reverse=True):
        if folder in created and folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()


def _mkdir(folder: Path, created: list[Path]) -> None:
    """Create ``folder`` (and parents), remembering which did not exist."""
    missing = [f for f in (folder, *folder.parents) if not f.exists()]
    folder.mkdir(parents=True, exist_ok=True)
    created += missing


def _export(
    store: RunStore | str | os.PathLike[str],
    out: str | os.PathLike[str],
    format: str,
    group: str,
    images: Sequence[int] | None,
    per_image: bool,
    progress: Callable[[str], None] | None,
    written: list[Path],
    created: list[Path],
) -> list[Path]:
    """:func:`export`; appends every file it starts (``.partial`` first) to ``written``."""
    if format not in FORMATS:
        raise ExportError.single("--format", f"one of {', '.join(FORMATS)}", repr(format))
    run = store if isinstance(store, RunStore) else RunStore.open(store)
    ds = select_images(_open(run, group), images)
    say = progress or (lambda message: None)
    out = Path(out)
    stem = _safe(f"{run.path.stem}_{group.replace('/', '-')}")
    if format == "envi":
        _mkdir(out, created)
        wavelength = np.asarray(ds["wavelength"].values, dtype=float)
        for position, label in enumerate(_labels(ds)):
            one = ds.isel(image=position)
            header: dict[str, Any] = {
                "description": f"spectralize {group} of {run.path.name}, image {label}: " + _UNITS_NOTE,
                "wavelength units": "Nanometers",
                "wavelength": wavelength.tolist(),
                "band names": [f"{w:g} nm" for w in wavelength],
                "data ignore value": ENVI_IGNORE,
                "spectralize image": label,
            }
            precision = Precision.stated(ds["radiance"].attrs)
            if precision is not None:
                header["spectralize precision bound relative"] = precision.relative_bound
            for name in _PER_IMAGE:
                if name in one.coords:
                    header[f"spectralize {name}"] = one[name].values.item()
            base = out / f"{stem}_image{label}"
            written += [base.with_suffix(".hdr"), base.with_suffix(".img")]
            _write_envi(one["radiance"], base, header)
            say(f"{written[-2].name}: image {label} ({position + 1}/{ds.sizes['image']})")
        return written
    cf = _netcdf_dataset(ds, run, group)
    if per_image:
        _mkdir(out, created)
        targets = [
            (cf.isel(image=[p]), out / f"{stem}_image{label}.nc") for p, label in enumerate(_labels(ds))
        ]
    else:
        # a folder (existing, or a name without a suffix): a .nc file in it
        target = out / f"{stem}.nc" if out.is_dir() or not out.suffix else out
        _mkdir(target.parent, created)
        targets = [(cf, target)]
    for data, target in targets:
        partial = target.with_name(target.name + ".partial")
        written.append(target)
        data.to_netcdf(partial, engine="h5netcdf", format="NETCDF4")
        os.replace(partial, target)
        say(f"{target.name}: {data.sizes['image']} image(s)")
    return written
