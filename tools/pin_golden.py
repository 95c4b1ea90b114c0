"""Pin the golden outputs of the public commands (tests/golden/pin.py) into tests/golden/reference.

Run only when a change of output is intended, and explain it in the commit that re-pins::

    .venv/bin/python tools/pin_golden.py

After pinning, the commands run again with the renderer compiled for another CPU (AVX2 at 8
lanes, ``STARNAV_LLVM_TARGET``) and are compared with the new pins: a pin that only this CPU
reproduces is reported, and the exit status is 1.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.golden.pin import compare_outputs, load_reference, outputs  # noqa: E402

OTHER_TARGET = "znver3;+avx2,+fma;8"


def main() -> int:
    ref = ROOT / "tests" / "golden" / "reference"
    ref.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as d:
        arrays, values = outputs(Path(d))
    np.savez_compressed(ref / "arrays.npz", **arrays)
    (ref / "values.json").write_text(json.dumps(values, indent=1, sort_keys=True) + "\n")
    print(f"pinned {len(arrays)} arrays and {len(values)} values into {ref}")
    os.environ["STARNAV_LLVM_TARGET"] = OTHER_TARGET
    with tempfile.TemporaryDirectory() as d:
        other = outputs(Path(d))
    diffs = compare_outputs(*other, *load_reference(ref))
    if diffs:
        print(f"the pins do not hold for target {OTHER_TARGET}:\n  " + "\n  ".join(diffs[:20]))
        return 1
    print(f"the pins hold for target {OTHER_TARGET} too")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
