#!/bin/bash
# The Debian 13 (trixie) guest's root filesystem, for the VM tests that run
# on the release users have now (`Userland::Debian13` in tests/src/vm.rs;
# `vmrun -r`): a debootstrapped tree with trixie's kernel and v4l2loopback
# built for it by DKMS, systemd, PipeWire 1.4 + WirePlumber 0.5, the camera
# portal, Chromium, GStreamer, ffmpeg and lintian. The guest boots it with
# its own kernel; the workspace is shared into it, so the binaries built on
# the host run there.
#
# usage: sudo tests/vm/debian13-root.sh [--rebuild]
# Built once into $SDI_DEBIAN13_ROOT (default /var/lib/sdi-test/debian13-root,
# about 2.3 GB; 2 min here), rebuilt when the package list below changes.
# Everything comes from Debian's mirror (the one this machine's apt uses, or
# $SDI_DEBIAN_MIRROR).
set -eEuo pipefail
STEP=start
step() { STEP=$*; echo "== debian13-root: $STEP"; }
trap 'rc=$?; echo "debian13-root.sh: step \"$STEP\" failed at line $LINENO (exit $rc): $BASH_COMMAND" >&2; exit $rc' ERR
export DEBIAN_FRONTEND=noninteractive

ROOT=${SDI_DEBIAN13_ROOT:-/var/lib/sdi-test/debian13-root}
REBUILD=0
[ "${1:-}" = --rebuild ] && REBUILD=1
[ "$(id -u)" = 0 ] || { echo "debian13-root.sh: run as root (debootstrap, chroot)" >&2; exit 2; }

# What the guest's tests run: the kernel, its headers and v4l2loopback's
# DKMS source (built for trixie's kernel at install); systemd, udev and the
# buses; PipeWire, WirePlumber, the portal, GStreamer's pipewiresrc and
# v4l2src; Chromium; ffmpeg and v4l-utils; lintian (the package against
# trixie's lintian); libusb (sdid's one library beyond libc).
PKGS="linux-image-amd64 linux-headers-amd64 v4l2loopback-dkms dkms kmod
      systemd systemd-sysv udev dbus dbus-user-session libusb-1.0-0
      pipewire pipewire-bin wireplumber xdg-desktop-portal gstreamer1.0-pipewire
      gstreamer1.0-tools gstreamer1.0-plugins-base gstreamer1.0-plugins-good
      chromium ffmpeg v4l-utils lintian procps iproute2 python3"
KEY="trixie minbase $(echo $PKGS | tr -s ' \n' ' ')"

if [ "$REBUILD" = 0 ] && [ -d "$ROOT" ] && [ "$(head -1 "$ROOT.stamp" 2>/dev/null || true)" = "$KEY" ]; then
    echo "debian13-root: $ROOT is up to date ($(sed -n 2p "$ROOT.stamp"))"
    exit 0
fi

step "debootstrap"
command -v debootstrap >/dev/null || apt-get install -y -qq debootstrap >/dev/null
MIRROR=${SDI_DEBIAN_MIRROR:-$(apt-get indextargets --format '$(REPO_URI)' | sort -u \
    | awk '/\/debian\/?$/ && !/security/ { print; exit }')}
[ -n "$MIRROR" ] || MIRROR=http://deb.debian.org/debian
NEW=$ROOT.new
mounted=()
cleanup() {
    local m
    for ((i = ${#mounted[@]} - 1; i >= 0; i--)); do umount -l "${mounted[i]}" 2>/dev/null || true; done
}
trap cleanup EXIT
rm -rf "$NEW"
mkdir -p "$(dirname "$ROOT")"
t0=$SECONDS
debootstrap --variant=minbase --arch=amd64 trixie "$NEW" "$MIRROR" >"$NEW.log" 2>&1 \
    || { tail -30 "$NEW.log" >&2; exit 1; }

step "packages ($MIRROR)"
for m in proc sys dev dev/pts; do
    mount --bind "/$m" "$NEW/$m"
    mounted+=("$NEW/$m")
done
cat /etc/resolv.conf >"$NEW/etc/resolv.conf"
# No service starts inside the chroot.
printf '#!/bin/sh\nexit 101\n' >"$NEW/usr/sbin/policy-rc.d"
chmod 755 "$NEW/usr/sbin/policy-rc.d"
chroot "$NEW" apt-get update -qq
# shellcheck disable=SC2086 # one word per package
chroot "$NEW" apt-get install -y -q --no-install-recommends $PKGS >>"$NEW.log" 2>&1 \
    || { tail -30 "$NEW.log" >&2; exit 1; }
chroot "$NEW" apt-get clean
rm -f "$NEW/usr/sbin/policy-rc.d"
cleanup
mounted=()
kver=$(ls "$NEW/lib/modules" | sort -V | tail -1)
ls "$NEW/lib/modules/$kver/updates/dkms/"v4l2loopback.ko* >/dev/null \
    || { echo "debian13-root.sh: DKMS built no v4l2loopback for $kver" >&2; exit 1; }

step "done"
rm -rf "$ROOT"
mv "$NEW" "$ROOT"
mv "$NEW.log" "$ROOT.log"
printf '%s\nbuilt %s in %s s: kernel %s\n' "$KEY" "$(date -Is)" "$((SECONDS - t0))" "$kver" >"$ROOT.stamp"
echo "debian13-root: $ROOT built in $((SECONDS - t0)) s (kernel $kver)"
