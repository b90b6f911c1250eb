#!/usr/bin/env bash
# Install the system libraries the stack needs, only when missing (idempotent, quick when nothing is missing).
#   libllvm19    - Dr.Jit's LLVM backend (Mitsuba llvm_ad_rgb); Debian's LLVM 14-16 are refused or abort.
#   libusb-1.0-0 - imported by open3d.
set -euo pipefail
need=()
for pkg in libllvm19 libusb-1.0-0; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || need+=("$pkg")
done
[ ${#need[@]} -eq 0 ] && exit 0
if [ "$(id -u)" != 0 ]; then SUDO=sudo; else SUDO=; fi
echo "installing system packages: ${need[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
