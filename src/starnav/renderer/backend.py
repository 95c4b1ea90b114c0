"""Choice of the Mitsuba variant at run time: cuda, then llvm (only with libLLVM >= 16), then
scalar.

libLLVM 14 and 15 abort Dr.Jit ("Cannot select fmaximum"): :func:`find_llvm` looks for
libLLVM >= 16 (``DRJIT_LIBLLVM_PATH``, the linker cache, the usual Debian locations) and
:func:`activate` sets ``DRJIT_LIBLLVM_PATH`` before the llvm variant is tried; without one
the scalar variant is used. The choice is recorded (:func:`current`) in every image's metadata.

``STARNAV_LLVM_TARGET="cpu;features;width"`` (e.g. ``znver3;+avx2,+fma;8``) compiles the
kernels for another CPU (``jit_llvm_set_target``), to reproduce its float32 rounding;
:func:`llvm_target` reports the target in use.
"""

from __future__ import annotations

import ctypes.util
import glob
import logging
import os
import re
import subprocess
from dataclasses import asdict, dataclass, field
from pathlib import Path

from starnav.errors import BackendError

log = logging.getLogger(__name__)

#: Oldest libLLVM major version that Dr.Jit can use without aborting.
MIN_LLVM_MAJOR = 16
DEFAULT_VARIANTS = ("cuda_ad_spectral", "llvm_ad_spectral", "scalar_spectral")
#: Environment variable naming the LLVM target Dr.Jit compiles for (module docstring).
TARGET_ENV = "STARNAV_LLVM_TARGET"
_LLVM_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
)


@dataclass(frozen=True)
class LLVMCandidate:
    path: str
    major: int


@dataclass
class BackendInfo:
    """What :func:`activate` chose and why."""

    variant: str
    llvm_path: str | None = None
    llvm_major: int | None = None
    llvm_target: dict[str, object] | None = None
    mitsuba_version: str = ""
    drjit_version: str = ""
    tried: list[str] = field(default_factory=list)
    preference: list[str] = field(default_factory=list)
    reasons: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict:
        return asdict(self)


_CURRENT: BackendInfo | None = None


def llvm_major_from_name(path: str) -> int | None:
    """Major version from a libLLVM file name: ``libLLVM-15.so.1`` -> 15,
    ``libLLVM.so.19.1`` -> 19, ``libLLVM-17.0.6.so`` -> 17; ``None`` if it has none."""
    name = Path(path).name
    m = re.match(r"libLLVM-(\d+)", name)
    if m:
        return int(m.group(1))
    m = re.match(r"libLLVM\.so\.(\d+)", name)
    if m:
        return int(m.group(1))
    m = re.search(r"llvm-(\d+)", path)
    if m:
        return int(m.group(1))
    return None


def _ldconfig_paths() -> list[str]:
    try:
        out = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True, timeout=10,
                             check=False).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    return [line.split("=>")[-1].strip() for line in out.splitlines() if "libLLVM" in line]


def llvm_candidates() -> list[LLVMCandidate]:
    """Every libLLVM found on this machine with its major version, newest first."""
    seen: dict[str, LLVMCandidate] = {}
    paths = _ldconfig_paths()
    for pattern in _LLVM_GLOBS:
        paths += glob.glob(pattern)
    lib = ctypes.util.find_library("LLVM")
    if lib:
        paths.append(lib)
    for p in paths:
        major = llvm_major_from_name(p)
        if major is not None and os.path.exists(p):
            real = os.path.realpath(p)
            if real not in seen or seen[real].major < major:
                seen[real] = LLVMCandidate(p, major)
    return sorted(seen.values(), key=lambda c: (-c.major, len(c.path)))


def find_llvm() -> LLVMCandidate | None:
    """A libLLVM >= 16 for Dr.Jit: ``DRJIT_LIBLLVM_PATH`` if set and new enough, otherwise
    the newest one found. ``None`` if there is none (then llvm variants must not be used)."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        major = llvm_major_from_name(env)
        if os.path.exists(env) and major is not None and major >= MIN_LLVM_MAJOR:
            return LLVMCandidate(env, major)
        log.warning("DRJIT_LIBLLVM_PATH=%s is missing or older than LLVM %d; ignoring it",
                    env, MIN_LLVM_MAJOR)
    for cand in llvm_candidates():
        if cand.major >= MIN_LLVM_MAJOR:
            return cand
    return None


def _drjit_core() -> ctypes.CDLL | None:
    """Dr.Jit's core library (its C++ API is not exposed to Python); ``None`` if absent."""
    import drjit as dr

    for name in ("libdrjit-core.so", "libdrjit-core.dylib"):
        path = Path(dr.__file__).with_name(name)
        if path.exists():
            return ctypes.CDLL(str(path))
    return None


def _symbol(lib: ctypes.CDLL, name: str, mangled: str) -> object | None:
    for n in (mangled, name):
        try:
            return getattr(lib, n)
        except AttributeError:
            continue
    return None


def parse_target(text: str) -> tuple[str, str | None, int]:
    """``"cpu;features;width"`` -> ``(cpu, features or None, width)``, checked."""
    parts = text.split(";")
    expected = ("'cpu;features;width' with a CPU name, LLVM features including +fma "
                "(Dr.Jit emits fused multiply-adds) and a power-of-two vector width, "
                "e.g. 'znver3;+avx2,+fma;8'")
    if len(parts) != 3 or not parts[0].strip():
        raise BackendError(f"{TARGET_ENV}={text!r}: expected {expected}")
    cpu, features, width = (p.strip() for p in parts)
    try:
        w = int(width)
    except ValueError:
        raise BackendError(f"{TARGET_ENV}={text!r}: expected {expected}") from None
    if w < 1 or w > 64 or w & (w - 1):
        raise BackendError(f"{TARGET_ENV}={text!r}: width {w}: expected {expected}")
    if features and "+fma" not in features.split(","):
        raise BackendError(f"{TARGET_ENV}={text!r}: no +fma: expected {expected}")
    return cpu, features or None, w


def set_llvm_target(cpu: str, features: str | None, width: int) -> None:
    """Make Dr.Jit compile every later LLVM kernel for ``cpu`` with ``features`` and
    ``width`` lanes (after the llvm variant is active)."""
    lib = _drjit_core()
    fn = None if lib is None else _symbol(lib, "jit_llvm_set_target",
                                          "_Z19jit_llvm_set_targetPKcS0_j")
    if fn is None:
        raise BackendError(f"{TARGET_ENV}: this Dr.Jit build does not expose "
                           "jit_llvm_set_target")
    fn.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32]
    fn.restype = None
    fn(cpu.encode(), None if features is None else features.encode(), width)


def llvm_target() -> dict[str, object] | None:
    """The CPU, features and vector width Dr.Jit's LLVM backend compiles for; ``None`` when
    it cannot be asked."""
    lib = _drjit_core()
    if lib is None:
        return None
    cpu = _symbol(lib, "jit_llvm_target_cpu", "_Z19jit_llvm_target_cpuv")
    feats = _symbol(lib, "jit_llvm_target_features", "_Z24jit_llvm_target_featuresv")
    width = _symbol(lib, "jit_llvm_vector_width", "_Z21jit_llvm_vector_widthv")
    if cpu is None or feats is None or width is None:
        return None
    cpu.restype = feats.restype = ctypes.c_char_p
    width.restype = ctypes.c_uint32
    raw = feats() or b""
    enabled = sorted(f[1:] for f in raw.decode().split(",") if f.startswith("+"))
    simd = [f for f in enabled if f in ("sse4.2", "avx", "avx2", "fma", "avx512f", "neon")]
    return {"cpu": (cpu() or b"").decode(), "vector_width": int(width()), "simd": simd}


def _cuda_available() -> bool:
    return ctypes.util.find_library("cuda") is not None or os.path.exists("/dev/nvidia0")


def activate(preference: tuple[str, ...] | list[str] = DEFAULT_VARIANTS) -> BackendInfo:
    """Select the first usable Mitsuba variant in ``preference``, register starnav's plugins
    and return what was chosen. Calling it again with the same choice is cheap."""
    global _CURRENT
    import drjit as dr
    import mitsuba as mi

    preference = tuple(preference)
    if _CURRENT is not None and _CURRENT.tried and tuple(_CURRENT.preference) == preference \
            and mi.variant() == _CURRENT.variant:
        return _CURRENT
    available = set(mi.variants())
    info = BackendInfo(variant="", mitsuba_version=mi.__version__, drjit_version=dr.__version__,
                       preference=list(preference))
    llvm = None
    for variant in preference:
        info.tried.append(variant)
        if variant not in available:
            info.reasons[variant] = "not compiled in this Mitsuba build"
            continue
        if variant.startswith("cuda") and not _cuda_available():
            info.reasons[variant] = "no CUDA driver"
            continue
        if variant.startswith("llvm"):
            llvm = llvm or find_llvm()
            if llvm is None:
                info.reasons[variant] = f"no libLLVM >= {MIN_LLVM_MAJOR} found"
                continue
            os.environ["DRJIT_LIBLLVM_PATH"] = llvm.path
        try:
            mi.set_variant(variant)
            if variant.startswith("llvm") and not dr.has_backend(dr.JitBackend.LLVM):
                raise BackendError("Dr.Jit could not initialise its LLVM backend")
            if variant.startswith("cuda") and not dr.has_backend(dr.JitBackend.CUDA):
                raise BackendError("Dr.Jit could not initialise its CUDA backend")
        except Exception as err:  # noqa: BLE001 - any failure means: try the next one
            info.reasons[variant] = f"failed: {err}"
            continue
        info.variant = variant
        if variant.startswith("llvm") and llvm is not None:
            info.llvm_path, info.llvm_major = llvm.path, llvm.major
            forced = os.environ.get(TARGET_ENV)
            if forced:
                set_llvm_target(*parse_target(forced))
            info.llvm_target = llvm_target()
        break
    if not info.variant:
        raise BackendError(f"no usable Mitsuba variant among {list(preference)}: {info.reasons}")
    from starnav.renderer.bsdfs import register_plugins  # lazy: mitsuba (bsdfs imports it)

    register_plugins()
    log.info("Mitsuba variant %s (LLVM: %s)", info.variant, info.llvm_path or "not used")
    _CURRENT = info
    return info


def versions() -> dict[str, object]:
    """Mitsuba and Dr.Jit versions and the variants compiled into this Mitsuba build."""
    import drjit as dr
    import mitsuba as mi

    return {"mitsuba": mi.__version__, "drjit": dr.__version__, "variants": list(mi.variants())}


def current() -> BackendInfo | None:
    """The last choice made by :func:`activate` (``None`` before the first call)."""
    return _CURRENT
