"""Variant selection: libLLVM versions that abort Dr.Jit are never handed to it; without a
usable LLVM the scalar variant is chosen, never a crash."""

from __future__ import annotations

import pytest

from starnav.errors import BackendError
from starnav.renderer import backend


@pytest.mark.parametrize("name,major", [
    ("/lib/x86_64-linux-gnu/libLLVM-15.so.1", 15),
    ("/lib/x86_64-linux-gnu/libLLVM.so.19.1", 19),
    ("/usr/lib/llvm-17/lib/libLLVM.so", 17),
    ("/usr/lib/x86_64-linux-gnu/libLLVM-14.so", 14),
    ("/opt/lib/libLLVM-18.1.so", 18),
])
def test_llvm_major_from_name(name, major):
    assert backend.llvm_major_from_name(name) == major


def test_old_llvm_in_environment_is_ignored(monkeypatch, tmp_path):
    old = tmp_path / "libLLVM-15.so.1"
    old.write_bytes(b"")
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(old))
    monkeypatch.setattr(backend, "llvm_candidates", lambda: [
        backend.LLVMCandidate(str(old), 15), backend.LLVMCandidate("/x/libLLVM-14.so", 14)])
    assert backend.find_llvm() is None


def test_newest_usable_llvm_is_chosen(monkeypatch, tmp_path):
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(backend, "llvm_candidates", lambda: [
        backend.LLVMCandidate("/a/libLLVM.so.19.1", 19),
        backend.LLVMCandidate("/a/libLLVM-15.so.1", 15)])
    assert backend.find_llvm() == backend.LLVMCandidate("/a/libLLVM.so.19.1", 19)


def test_without_llvm_falls_back_to_scalar(monkeypatch):
    monkeypatch.setattr(backend, "find_llvm", lambda: None)
    monkeypatch.setattr(backend, "_CURRENT", None)
    info = backend.activate(("cuda_ad_spectral", "llvm_ad_spectral", "scalar_spectral"))
    assert info.variant == "scalar_spectral"
    assert "no libLLVM >= 16" in info.reasons["llvm_ad_spectral"]
    import mitsuba as mi

    assert mi.variant() == "scalar_spectral"
    # a scalar render works and the photometric plugins are registered for it
    from starnav.renderer.bsdfs import PLUGIN_NAMES

    bsdf = mi.load_dict({"type": PLUGIN_NAMES["lommel_seeliger"], "albedo": 0.2})
    assert bsdf is not None


def test_default_choice_uses_llvm_19_when_present():
    cands = [c for c in backend.llvm_candidates() if c.major >= backend.MIN_LLVM_MAJOR]
    if not cands:
        pytest.skip("no libLLVM >= 16 on this machine (CI installs libllvm19)")
    info = backend.activate(("llvm_ad_spectral", "scalar_spectral"))
    assert info.variant == "llvm_ad_spectral"
    assert info.llvm_major >= 16


@pytest.mark.parametrize("text", ["znver3", "znver3;+avx2;8", "znver3;+avx2,+fma;6",
                                  "znver3;+avx2,+fma;eight", ";+fma;8"])
def test_a_malformed_llvm_target_is_refused_by_name(text):
    from starnav.renderer.backend import TARGET_ENV, parse_target

    with pytest.raises(BackendError, match=TARGET_ENV):
        parse_target(text)


def test_llvm_target_parses():
    from starnav.renderer.backend import parse_target

    assert parse_target("znver3;+avx2,+fma;8") == ("znver3", "+avx2,+fma", 8)
    assert parse_target("generic;;4") == ("generic", None, 4)
