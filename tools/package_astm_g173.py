"""Write the packaged ASTM G-173 extraterrestrial solar spectrum, ``starnav/data/sun``.

starnav's default Sun (:func:`starnav.spectra.solar_spectrum`, ``"astm-g173"``) is the ASTM
G-173-03 extraterrestrial (ETR) column as colour-science ships it
(``colour.plotting.datasets.astm_g_173.SD_ASTMG173_ETR``). Reading it from colour imports the
whole ``colour`` package (4 s on the 2-core development machine, at every worker start:
issue 18), so the 2 002 samples are shipped as a CSV, written by this script with the
shortest round-trip ``repr`` of each float (read back, the arrays are bit for bit colour's).
Run it again only to take a new colour release's table::

    .venv/bin/python tools/package_astm_g173.py

``tests/test_spectra.py`` checks the packaged table against colour's (equal arrays) and its
integral against the published figure.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import colour
import numpy as np
from colour.plotting.datasets.astm_g_173 import SD_ASTMG173_ETR

OUT = Path(__file__).resolve().parents[1] / "src" / "starnav" / "data" / "sun" / \
    "astm_g173_etr.csv"


def main() -> None:
    w = np.asarray(SD_ASTMG173_ETR.wavelengths, float)
    v = np.asarray(SD_ASTMG173_ETR.values, float)
    rows = (f"{float(a)!r},{float(b)!r}\n" for a, b in zip(w, v, strict=True))
    text = "wavelength_nm,etr_w_m2_nm\n" + "".join(rows)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(text, encoding="ascii")
    print(f"{OUT}: {w.size} samples from colour {colour.__version__}, sha256 "
          f"{hashlib.sha256(text.encode()).hexdigest()}")


if __name__ == "__main__":
    main()
