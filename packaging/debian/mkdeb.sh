#!/bin/bash
# Builds the Debian packages from binaries that are already built (`make
# deb` builds them first; `make deb-package TARGETDIR=...` packages any
# build, e.g. the tests' debug binaries):
#
#   sdi                  sdid, sdictl and everything `make install PREFIX=/usr`
#                        installs, plus /usr/share/doc/sdi/{copyright,changelog.Debian.gz}
#   sdi-pipewire-camera  /usr/libexec/sdi/sdi-pipewire-camera, only when
#                        TARGETDIR holds that program
#
# usage: mkdeb.sh TARGETDIR DEBDIR     (run from the top of the source tree)
#
# Why plain dpkg-deb over a staging tree rather than cargo-deb: the tree is
# filled by the Makefile's own `make install DESTDIR=...`, so the package
# holds exactly the files a source install puts in place (one list, tested
# by tests/tests/system_files.rs), and the tools are dpkg's (dpkg-deb,
# dpkg-shlibdeps), on every Debian machine that builds SDI; cargo-deb would
# keep a second file list in Cargo.toml and need a `cargo install` in CI.
set -eEuo pipefail
trap 'echo "mkdeb.sh: failed at line $LINENO: $BASH_COMMAND" >&2' ERR

[ $# -eq 2 ] || { echo "usage: $0 TARGETDIR DEBDIR" >&2; exit 2; }
TARGETDIR=$(realpath "$1")
mkdir -p "$2"
DEBDIR=$(realpath "$2")
HERE=packaging/debian
[ -f "$HERE/changelog" ] || { echo "mkdeb.sh: run from the top of the source tree" >&2; exit 2; }
MAKE=${MAKE:-make}
DEB_REVISION=${DEB_REVISION:-1}
# dpkg-deb's compressor; the tests pass a faster one (-Zgzip -z1).
DEB_COMPRESS=${DEB_COMPRESS:--Zxz}

for tool in dpkg-deb dpkg-shlibdeps dpkg-parsechangelog strip objcopy; do
    command -v "$tool" >/dev/null || { echo "mkdeb.sh: $tool not found (apt-get install dpkg-dev binutils)" >&2; exit 1; }
done

# Version: the workspace's (Cargo.toml) plus the Debian revision; the top
# entry of packaging/debian/changelog must name exactly that version.
upstream=$(awk '/^\[workspace.package\]/ { p = 1; next } /^\[/ { p = 0 }
                p && $1 == "version" { gsub(/"/, "", $3); print $3; exit }' Cargo.toml)
[ -n "$upstream" ] || { echo "mkdeb.sh: no version in Cargo.toml's [workspace.package]" >&2; exit 1; }
VERSION=$upstream-$DEB_REVISION
logged=$(dpkg-parsechangelog -l "$HERE/changelog" -SVersion)
if [ "$logged" != "$VERSION" ]; then
    echo "mkdeb.sh: $HERE/changelog's newest entry is $logged, the package is $VERSION: add an entry (dch -v $VERSION)" >&2
    exit 1
fi
ARCH=$(dpkg --print-architecture)
# File times in the packages: the changelog entry's date (reproducible).
SOURCE_DATE_EPOCH=$(dpkg-parsechangelog -l "$HERE/changelog" -STimestamp)
export SOURCE_DATE_EPOCH
MAINTAINER=$(dpkg-parsechangelog -l "$HERE/changelog" -SMaintainer)

WORK=$DEBDIR/build
rm -rf "$WORK"
rm -f "$DEBDIR"/sdi_*.deb "$DEBDIR"/sdi-pipewire-camera_*.deb
mkdir -p "$WORK"

# ELF files under $1 lose their debug information and symbols, as dh_strip does.
is_elf() {
    [ "$(head -c 4 "$1" | od -An -c | tr -d ' ')" = '177ELF' ]
}

strip_tree() {
    find "$1" -type f | while read -r f; do
        if is_elf "$f"; then
            strip --remove-section=.comment --remove-section=.note --strip-unneeded "$f"
        fi
    done
}

# /usr/share/doc/PACKAGE: the copyright and the changelog.
add_docs() {
    local doc=$1/usr/share/doc/$2
    install -d "$doc"
    install -m 0644 "$HERE/copyright" "$doc/copyright"
    gzip -9n < "$HERE/changelog" > "$doc/changelog.Debian.gz"
}

# The shared libraries' packages the ELF files of a tree need.
# dpkg-shlibdeps wants a debian/control in its working directory (a scratch
# one) and finds the package's root by its DEBIAN directory.
shlibs_of() {
    local scratch=$WORK/shlibs-$2 elfs=() f
    mkdir -p "$scratch/debian" "$1/DEBIAN"
    printf 'Source: sdi\n\nPackage: %s\nArchitecture: any\n' "$2" > "$scratch/debian/control"
    while read -r f; do
        is_elf "$f" && elfs+=("-e$f")
    done < <(find "$1" -path "$1/DEBIAN" -prune -o -type f -print | sort)
    (cd "$scratch" && dpkg-shlibdeps -O "${elfs[@]}") | sed -n 's/^shlibs:Depends=//p'
}

# Modes as Debian wants them: 0755 directories and programs, 0644 the rest;
# owner root:root comes from dpkg-deb --root-owner-group.
normalize() {
    find "$1" -type d -exec chmod 0755 {} +
    find "$1" -type f -perm /111 -exec chmod 0755 {} +
    find "$1" -type f ! -perm /111 -exec chmod 0644 {} +
}

# DEBIAN/control, md5sums, conffiles (every file under /etc), then the .deb.
build_deb() {
    local root=$1 package=$2 depends=$3 extra=$4 description=$5
    install -d "$root/DEBIAN"
    normalize "$root"
    local size
    size=$(du -sk --exclude=DEBIAN "$root" | cut -f1)
    {
        echo "Package: $package"
        echo "Version: $VERSION"
        echo "Architecture: $ARCH"
        echo "Maintainer: $MAINTAINER"
        echo "Installed-Size: $size"
        echo "Depends: $depends"
        [ -n "$extra" ] && printf '%s\n' "$extra"
        echo "Section: video"
        echo "Priority: optional"
        printf 'Description: %s\n' "$description"
    } > "$root/DEBIAN/control"
    (cd "$root" && find . -path ./DEBIAN -prune -o -type f -printf '%P\0' | sort -z \
        | xargs -0 -r md5sum) > "$root/DEBIAN/md5sums"
    (cd "$root" && find etc -type f -printf '/%p\n' 2>/dev/null | sort) > "$root/DEBIAN/conffiles" || true
    [ -s "$root/DEBIAN/conffiles" ] || rm -f "$root/DEBIAN/conffiles"
    chmod 0644 "$root/DEBIAN/control" "$root/DEBIAN/md5sums"
    local deb=$DEBDIR/${package}_${VERSION}_${ARCH}.deb
    dpkg-deb --root-owner-group $DEB_COMPRESS --build "$root" "$deb" >/dev/null
    echo "$deb"
}

## sdi
ROOT=$WORK/sdi
"$MAKE" -s --no-print-directory install PREFIX=/usr DESTDIR="$ROOT" TARGETDIR="$TARGETDIR" GENDIR="$WORK/gen"
# The PipeWire camera has its own package, wherever `make install` put it,
# with the files that come with it (Makefile: install-camera-files).
rm -f "$ROOT/usr/bin/sdi-pipewire-camera" "$ROOT/usr/libexec/sdi/sdi-pipewire-camera"
rmdir -p "$ROOT/usr/libexec/sdi" 2>/dev/null || true
rm -rf "$ROOT/usr/share/wireplumber" "$ROOT/usr/lib/systemd/user/pipewire.service.wants"
rm -f "$ROOT/usr/lib/systemd/user/sdi-pipewire-camera.service"
strip_tree "$ROOT"
[ ! -d "$ROOT/usr/share/man" ] || find "$ROOT/usr/share/man" -type f ! -name '*.gz' -exec gzip -9n {} +
add_docs "$ROOT" sdi
for script in postinst prerm postrm; do
    install -D -m 0755 "$HERE/$script" "$ROOT/DEBIAN/$script"
done
board_ids=$(awk '!/^#/ && NF >= 2 { printf "%s%s:%s", sep, $1, $2; sep = " " }' udev/board-ids)
sed -i "s|@BOARD_IDS@|$board_ids|" "$ROOT/DEBIAN/postinst"
shlibs=$(shlibs_of "$ROOT" sdi)
# systemd-sysusers (postinst) is systemd's, or a standalone provider's.
build_deb "$ROOT" sdi "$shlibs, systemd | systemd-sysusers" \
    "Recommends: v4l2loopback-dkms, dbus
Suggests: sdi-pipewire-camera" \
    "difference camera on time-of-flight sensors (service and CLI)
 SDI drives a time-of-flight sensor (TI OPT8241-CDK, or a physically
 faithful simulator without one) as a snapshot difference camera: every
 frame is the analog difference of two light sources, for direct-only
 polarization, bipolar colour, depth edges and spatial and temporal
 gradients.
 .
 sdid publishes the chosen mode as a V4L2 camera through v4l2loopback (or
 a y4m stream, or a PipeWire camera with sdi-pipewire-camera) and is
 controlled over D-Bus; sdictl is its command-line client and offline
 tool. Plugging the board in starts the hardened system service; members
 of the group \"sdi\" control it."

## sdi-pipewire-camera (when it was built)
if [ -x "$TARGETDIR/sdi-pipewire-camera" ]; then
    CROOT=$WORK/sdi-pipewire-camera
    install -D -m 0755 "$TARGETDIR/sdi-pipewire-camera" "$CROOT/usr/libexec/sdi/sdi-pipewire-camera"
    "$MAKE" -s --no-print-directory install-camera-files PREFIX=/usr DESTDIR="$CROOT" GENDIR="$WORK/gen"
    strip_tree "$CROOT"
    add_docs "$CROOT" sdi-pipewire-camera
    shlibs=$(shlibs_of "$CROOT" sdi-pipewire-camera)
    build_deb "$CROOT" sdi-pipewire-camera "$shlibs, sdi (= $VERSION)" "" \
        "SDI difference camera as a PipeWire camera
 The program sdid starts in a desktop session to publish the SDI camera
 as PipeWire nodes, without the v4l2loopback module or beside it:
 PipeWire applications, GStreamer's pipewiresrc and browsers through the
 camera portal see one \"SDI camera\" that delivers frames (a WirePlumber
 rule keeps the loopback nodes, which PipeWire before 1.3.81 cannot read,
 out of PipeWire). The nodes outlive a restart of sdid, so readers keep
 their stream."
else
    echo "note: no $TARGETDIR/sdi-pipewire-camera: package sdi-pipewire-camera not built" >&2
fi
rm -rf "$WORK"
