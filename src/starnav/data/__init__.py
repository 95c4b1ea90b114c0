"""Real lunar data shipped inside the package (installed with ``pip install starnav``).

========================================  ==================================================
file (package-relative to ``starnav/data``)  what
========================================  ==================================================
``lola/LDEM_4.LBL`` + ``LDEM_4.IMG``      NASA LRO LOLA global heights, PDS product LDEM_4
                                          (720 x 1440, 4 px/deg, int16 half-metres above the
                                          1737.4 km sphere); ``lola/PROVENANCE.md``
``albedo/lroc_wac_grey_2048.tif``         LROC WAC mosaic (NASA SVS CGI Moon Kit) as one
                                          relative linear grey channel, 2048 x 1024 uint16
                                          GeoTIFF decoding to 0..1 (band scale 1/65535);
                                          ``albedo/PROVENANCE.md``,
                                          ``tools/convert_lroc_albedo.py``
========================================  ==================================================

Each folder carries a ``PROVENANCE.md``: origin, terms, format facts and how it was made.

Example
-------
>>> from starnav.data import LDEM_4_LABEL, packaged_path
>>> packaged_path(LDEM_4_LABEL).name
'LDEM_4.LBL'
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from starnav.errors import DataFileError

__all__ = ["LDEM_4_LABEL", "LROC_ALBEDO", "packaged_path"]

#: The PDS3 label of LOLA LDEM_4 (the ``.IMG`` lies beside it), package-relative.
LDEM_4_LABEL = "lola/LDEM_4.LBL"
#: The LROC WAC grey albedo map (relative linear brightness 0..1), package-relative.
LROC_ALBEDO = "albedo/lroc_wac_grey_2048.tif"


def packaged_path(relative: str) -> Path:
    """Filesystem path of a data file shipped in ``starnav/data``.

    Parameters
    ----------
    relative : str
        Path below ``starnav/data`` with ``/`` separators, e.g. :data:`LDEM_4_LABEL`.

    Returns
    -------
    pathlib.Path
        The file on disk (starnav is installed as plain files, not zipped: readers such as
        GDAL need a real path, and a PDS3 label needs its ``.IMG`` beside it).

    Raises
    ------
    DataFileError
        The file is not in the installed package (named in the message), or ``relative`` is
        absolute or leaves ``starnav/data``.
    """
    parts = [p for p in str(relative).replace("\\", "/").split("/") if p not in ("", ".")]
    if not parts or str(relative).startswith("/") or ".." in parts:
        raise DataFileError(f"packaged data file {relative!r}: expected a path inside "
                            "starnav/data, e.g. 'lola/LDEM_4.LBL'")
    res = files("starnav").joinpath("data", *parts)
    if not res.is_file():
        raise DataFileError(f"packaged data file {'starnav/data/' + '/'.join(parts)!r} is "
                            "missing from the installed starnav (reinstall starnav; in a "
                            "source tree: see the folder's PROVENANCE.md)")
    if not isinstance(res, Path):  # e.g. a zipped install: GDAL cannot read from inside it
        raise DataFileError(f"packaged data file {'/'.join(parts)!r} is not a plain file "
                            f"({res!r}); install starnav unzipped (pip install, not a zipapp)")
    return res
