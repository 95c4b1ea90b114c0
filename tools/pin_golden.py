"""Pin the golden outputs of the public commands (tests/golden/pin.py) into tests/golden/reference.

Run only when a change of output is intended and explained::

    .venv/bin/python tools/pin_golden.py
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.golden.pin import outputs  # noqa: E402


def main() -> None:
    ref = ROOT / "tests" / "golden" / "reference"
    ref.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as d:
        arrays, values = outputs(Path(d))
    np.savez_compressed(ref / "arrays.npz", **arrays)
    (ref / "values.json").write_text(json.dumps(values, indent=1, sort_keys=True) + "\n")
    print(f"pinned {len(arrays)} arrays and {len(values)} values into {ref}")


if __name__ == "__main__":
    main()
