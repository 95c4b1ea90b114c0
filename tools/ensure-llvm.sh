#!/usr/bin/env bash
# Make a libLLVM >= 16 available for Dr.Jit's CPU backend (Mitsuba's llvm variants).
# libLLVM 14 and 15 abort the process inside Dr.Jit, so they do not count. As root with apt,
# install Debian's libllvm19; otherwise say so and let starnav fall back to scalar_spectral.
set -u
have_llvm() {
  { ldconfig -p 2>/dev/null | grep -oE 'libLLVM[-.][^ ]*' ; ls /usr/lib/llvm-*/lib/libLLVM* 2>/dev/null; } \
    | grep -oE 'LLVM(-|\.so\.)[0-9]+|llvm-[0-9]+' | grep -oE '[0-9]+' \
    | awk '$1 >= 16 {found=1} END {exit !found}'
}
if have_llvm; then
  exit 0
fi
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
  echo "ensure-llvm: no libLLVM >= 16 found; installing Debian's libllvm19" >&2
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq >/dev/null && apt-get install -y -qq libllvm19 >/dev/null \
    || echo "ensure-llvm: could not install libllvm19; starnav will use scalar_spectral" >&2
  ldconfig 2>/dev/null || true
else
  echo "ensure-llvm: no libLLVM >= 16 and not root: starnav will use scalar_spectral" \
       "(install libllvm19 to get the fast llvm variant)" >&2
fi
exit 0
