"""RadianceImage: the renderer's output and the detector chain's input, and its OpenEXR file.

Channels (float32, ``(height, width)``, row 0 at the top)
---------------------------------------------------------
========== ======================= =====================================================
channel    unit                    meaning
========== ======================= =====================================================
``L``      W m^-2 sr^-1            band radiance: integral of L(lambda) over the band
``Le``     e- s^-1 m^-2 sr^-1      electron radiance: integral of L QE T lambda/(h c)
``range``  m                       camera to surface point along the pixel-centre ray
``nx ny nz`` -                     unit surface normal, Moon-centred inertial axes
``lat lon`` rad                    selenographic latitude and longitude (body-fixed)
``incidence emission phase`` rad   photometric angles at the pixel-centre surface point
``mask``   -                       1 where the pixel-centre ray hits the Moon, else 0
``x_body y_body z_body`` m         surface point in the body-fixed frame (shape-model
                                   bodies only: ``TargetModel.body_fixed_aovs``)
========== ======================= =====================================================

AOV channels hold the values at the pixel-centre ray (no averaging across the limb). Header
attributes (strings and floats) carry the frame geometry (JSON, Moon-centred inertial, SI), the
camera, the Sun's band integrals and the renderer's provenance; they round-trip through
:func:`write_exr` and :func:`read_exr`. Files are written to a temporary name and renamed.

The file is plain OpenEXR: any EXR reader gives the channels; ``json.loads`` of the
``starnav`` header attribute gives the metadata.
"""

from __future__ import annotations

import errno
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from starnav.atomic import atomic_path
from starnav.errors import DataFileError, not_a_file_error
from starnav.typing import Float32Array

RADIANCE_CHANNELS = ("L", "Le")
AOV_CHANNELS = ("range", "nx", "ny", "nz", "lat", "lon", "incidence", "emission", "phase", "mask")
#: Extra AOV channels of shape-model bodies: the body-fixed surface point [m].
BODY_FIXED_AOV_CHANNELS = ("x_body", "y_body", "z_body")
#: Name of the header attribute holding the JSON metadata.
META_ATTRIBUTE = "starnav"


@dataclass
class RadianceImage:
    """Band radiance and electron radiance of one frame, plus AOVs and metadata.

    Attributes
    ----------
    L : (H, W) float32
        Band radiance [W m^-2 sr^-1].
    Le : (H, W) float32
        Electron radiance [e- s^-1 m^-2 sr^-1].
    aovs : dict of (H, W) float32
        Auxiliary channels (see module docstring), possibly empty.
    meta : dict
        JSON-serialisable metadata: ``geometry``, ``camera``, ``sun``, ``render``.
    """

    L: Float32Array
    Le: Float32Array
    aovs: dict[str, Float32Array] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.L.shape)  # type: ignore[return-value]

    @property
    def mask(self) -> NDArray[np.bool_]:
        """Pixels whose centre ray hits the Moon (from the ``mask`` AOV, else ``L > 0``)."""
        if "mask" in self.aovs:
            return self.aovs["mask"] > 0.5
        return self.L > 0

    def channels(self) -> dict[str, Float32Array]:
        out = {"L": self.L, "Le": self.Le}
        out.update(self.aovs)
        return out


def write_exr(img: RadianceImage, path: str | os.PathLike[str]) -> Path:
    """Write ``img`` as a float32 OpenEXR (ZIP compressed), atomically. Returns the path."""
    import OpenEXR

    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    channels = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in img.channels().items()}
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        META_ATTRIBUTE: json.dumps(img.meta, sort_keys=True),
    }
    with atomic_path(p, suffix=".exr") as tmp, OpenEXR.File(header, channels) as f:
        try:
            f.write(str(tmp))
        except RuntimeError as err:  # OpenEXR reports a failed write (a full disk) so
            code = errno.ENOSPC if "space" in str(err).lower() else errno.EIO
            raise OSError(code, f"writing the EXR failed ({err})", str(p)) from None
    return p


def read_exr(path: str | os.PathLike[str]) -> RadianceImage:
    """Read a RadianceImage written by :func:`write_exr` (or any EXR with ``L`` and ``Le``)."""
    import OpenEXR

    p = Path(path)
    if not p.is_file():
        raise not_a_file_error(p, "radiance image")
    try:
        with OpenEXR.File(str(p), separate_channels=True) as f:
            chans = {k: np.asarray(v.pixels, dtype=np.float32) for k, v in f.channels().items()}
            raw = f.header().get(META_ATTRIBUTE, "{}")
    except (RuntimeError, ValueError, OSError) as err:
        # OpenEXR reports an empty, truncated or foreign file as a RuntimeError
        raise DataFileError(f"radiance image {str(p)!r} is not a readable OpenEXR file "
                            f"({p.stat().st_size} bytes: {err}); expected an EXR with channels "
                            "L and Le (starnav render)") from None
    for name in RADIANCE_CHANNELS:
        if name not in chans:
            raise DataFileError(f"{str(p)!r} has no channel {name!r}; channels: {sorted(chans)}")
    meta = json.loads(raw) if isinstance(raw, str) else {}
    aovs = {k: v for k, v in chans.items() if k not in RADIANCE_CHANNELS}
    return RadianceImage(chans["L"], chans["Le"], aovs, meta)
