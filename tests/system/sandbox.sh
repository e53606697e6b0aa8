#!/bin/sh
# Runs a command with (approximately) the file-system view systemd gives
# sdid.service, for tests on machines without systemd as PID 1:
#   StateDirectory=sdi     STATE_DIR appears as /var/lib/sdi, writable
#   PrivateTmp=yes         fresh, empty /tmp and /var/tmp
#   ProtectHome=yes        /home, /root, /run/user empty
#   ProtectSystem=strict   every other mount read-only (/proc, /sys, /dev aside)
# and INVOCATION_ID set, as for any systemd service. Run as root in a
# private mount namespace:
#   unshare --mount --propagation private sh tests/system/sandbox.sh STATE_DIR CMD [ARGS...]
set -eu
state=$1
shift
mount --make-rprivate /
mount -t tmpfs -o mode=0755 sdi-var-lib /var/lib
mkdir /var/lib/sdi
mount --bind "$state" /var/lib/sdi
# An installed sdid lives in /usr/bin; a test's may sit in a checkout under
# /tmp or /root, which the sandbox hides: run a copy from /var/lib instead.
if [ -f "$1" ]; then
    mkdir /var/lib/.sdi-sandbox-bin
    cp "$1" /var/lib/.sdi-sandbox-bin/
    prog=/var/lib/.sdi-sandbox-bin/$(basename "$1")
    shift
    set -- "$prog" "$@"
fi
mount -t tmpfs -o mode=1777 sdi-tmp /tmp
mount -t tmpfs -o mode=1777 sdi-var-tmp /var/tmp
for d in /home /root /run/user; do
    if [ -d "$d" ]; then mount -t tmpfs -o mode=0755 sdi-home "$d"; fi
done
awk '{ print $5 }' /proc/self/mountinfo | sort -u | while read -r mp; do
    case $mp in
    /proc | /proc/* | /sys | /sys/* | /dev | /dev/* | /var/lib/sdi | /tmp | /var/tmp) ;;
    *) mount -o remount,bind,ro "$mp" 2>/dev/null || true ;;
    esac
done
if touch /etc/.sdi-sandbox-probe 2>/dev/null; then
    rm -f /etc/.sdi-sandbox-probe
    echo "sandbox.sh: could not make / read-only" >&2
    exit 1
fi
export INVOCATION_ID=sdi-sandbox
# StateDirectory=sdi: systemd names it to the service.
export STATE_DIRECTORY=/var/lib/sdi
exec "$@"
