#!/usr/bin/env bash
# Installs the Vulkan loader and Mesa's lavapipe (CPU Vulkan driver).
# Mesa from bookworm-backports runs compute ~5x faster than bookworm's 22.3, so we add that suite,
# deriving its mirror from the machine's own Debian apt entries (no registry host is named here).
set -euo pipefail

if [ "$(id -u)" != 0 ]; then SUDO=sudo; else SUDO=; fi

codename=$(. /etc/os-release && echo "${VERSION_CODENAME:-}")
backports_list=/etc/apt/sources.list.d/raypatch-backports.list
if [ -n "$codename" ] && [ ! -f "$backports_list" ]; then
  # First main-archive mirror among the existing entries (deb822 .sources files or one-line lists).
  mirror=$(grep -hE '^URIs:' /etc/apt/sources.list.d/*.sources 2>/dev/null | awk '{print $2}' | grep -v security | head -n1 || true)
  if [ -z "$mirror" ]; then
    mirror=$(grep -hE '^deb ' /etc/apt/sources.list /etc/apt/sources.list.d/*.list 2>/dev/null \
      | grep -v security | awk -v c="$codename" '$3==c {print $2}' | head -n1 || true)
  fi
  if [ -n "$mirror" ]; then
    echo "deb $mirror ${codename}-backports main" | $SUDO tee "$backports_list" >/dev/null
  fi
fi

$SUDO apt-get update -qq
if [ -f "$backports_list" ]; then
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq -t "${codename}-backports" \
    mesa-vulkan-drivers libvulkan1 >/dev/null \
  || $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
else
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mesa-vulkan-drivers libvulkan1 >/dev/null
fi
dpkg-query -W -f='${Package} ${Version}\n' mesa-vulkan-drivers libvulkan1
