#!/usr/bin/env bash
# Makes (or finds) the Debian trixie chroot whose Mesa 26 lavapipe has cooperative matrices (8x8x8 f16 at subgroup
# scope), for .ci/coop.sh. Prints the chroot's path on stdout as its last line; exits 3, saying why on stderr, where
# this machine cannot make it (not root, no debootstrap mirror, a CPU without AVX2: llvmpipe narrower than 256 bits
# has no cooperative matrices).
#
# Kept between runs at $RAYPATCH_COOP_ROOT (default /var/cache/raypatch/coop-trixie): a fresh machine pays about
# 75 s (debootstrap ~60 s, Mesa ~15 s); a machine that keeps /var/cache pays nothing.
set -euo pipefail

root=${RAYPATCH_COOP_ROOT:-/var/cache/raypatch/coop-trixie}
stamp="$root/.raypatch-coop-ready"

why_not() { echo "coop: $1" >&2; exit 3; }

[ "$(id -u)" = 0 ] || why_not "making the Mesa 26 chroot needs root (debootstrap, mounts); not run"
grep -qw avx2 /proc/cpuinfo || why_not "this CPU has no AVX2: llvmpipe is narrower than 256 bits and has no cooperative matrices"

if [ ! -f "$stamp" ]; then
  command -v debootstrap >/dev/null || {
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends debootstrap >/dev/null
  }
  # The machine's own Debian mirror, as install-lavapipe.sh finds it (no registry host is named here).
  mirror=$(grep -hE '^URIs:' /etc/apt/sources.list.d/*.sources 2>/dev/null | awk '{print $2}' | grep -v security | head -n1 || true)
  if [ -z "$mirror" ]; then
    mirror=$(grep -hE '^deb ' /etc/apt/sources.list /etc/apt/sources.list.d/*.list 2>/dev/null \
      | grep -v security | awk '{print $2}' | head -n1 || true)
  fi
  [ -n "$mirror" ] || why_not "no Debian mirror among this machine's apt sources"
  rm -rf "$root"
  mkdir -p "$root"
  debootstrap --variant=minbase trixie "$root" "$mirror" >/dev/null \
    || why_not "debootstrap of trixie from $mirror failed"
  echo "deb $mirror trixie-backports main" > "$root/etc/apt/sources.list.d/backports.list"
  chroot "$root" apt-get update -qq
  # vulkan-validationlayers: the validation run of coop.sh (Khronos' layer must print no error).
  chroot "$root" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
    -t trixie-backports mesa-vulkan-drivers libvulkan1 vulkan-validationlayers >/dev/null \
    || why_not "installing trixie-backports' mesa-vulkan-drivers in the chroot failed"
  chroot "$root" dpkg-query -W -f='${Package} ${Version}\n' mesa-vulkan-drivers vulkan-validationlayers >&2
  touch "$stamp"
fi
echo "$root"
