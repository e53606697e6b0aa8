#!/bin/bash
# Proves the README's two set-up commands work on a brand-new user's machine:
# a Debian 12 or 13 minbase root (debootstrap, plus only build-essential, git, dbus,
# python3 and ca-certificates), this machine's Rust toolchain copied in with
# an EMPTY cargo home (no crate cache), a fresh clone of the project as a
# normal user's checkout, and a clean environment (env -i: PATH, HOME, USER,
# LANG; no XDG_RUNTIME_DIR, no session bus, no v4l2loopback, no PipeWire).
#
# The two commands are read from README.md of the checked-out ref: the first
# two ```sh blocks under the "## Set-up" heading.
#   1. the main job (sdid on the simulator): runs in the background; checked:
#      it builds, stays up UP_SECS after the build, and publishes frames
#      (reads the y4m FIFO sdid announces and expects "YUV4MPEG2"); then
#      stopped with SIGINT (SIGKILL after 20 s).
#   2. the tests: exit code, duration, summed "test result:" lines, and every
#      line that says it skips (run with RUST_TEST_NOCAPTURE=1, so libtest
#      does not swallow the skip messages of passing tests; --exact-env
#      leaves it out). Not run when command 1 did not build (--tests-anyway).
#
# The debootstrapped root is cached (default /var/tmp/sdi-fresh-root, keyed by
# a stamp file; --rebuild forces a new one) and never modified: each run works
# in an overlayfs over it (a full copy if overlayfs is unavailable), removed
# at the end (--keep leaves it). Everything comes from Debian's mirror (the
# one this machine's apt uses) and crates.io; nothing prebuilt is downloaded.
#
#   tests/fresh-machine/run.sh [--repo DIR] [--ref REV] [--as-root] ...   (root)
#   tests/fresh-machine/run.sh --help
set -eEuo pipefail
export LC_ALL=C.UTF-8

SCRIPT_DIR=$(cd "$(dirname "$0")" && pwd)
REPO=
REF=HEAD
CACHE=
RELEASE=12
LOGS=${SDI_FRESH_LOGS:-/var/tmp/sdi-fresh-machine-logs}
MIRROR=
REBUILD=0
KEEP=0
AS_ROOT=0
RUNTIME_DIR=0
TESTS_ANYWAY=0
EXACT_ENV=0
BUILD_TIMEOUT_MIN=${BUILD_TIMEOUT_MIN:-40}
TEST_TIMEOUT_MIN=${TEST_TIMEOUT_MIN:-90}
DEBOOTSTRAP_TIMEOUT_MIN=30
UP_SECS=20
FRAME_WAIT_SECS=30
INCLUDE=build-essential,git,dbus,python3,ca-certificates

usage() {
    cat <<EOF
usage: $0 [options]          (as root)
  --repo DIR          repository to clone (default: the one holding this script)
  --ref REV           revision to check out (default HEAD of --repo)
  --release 12|13     the Debian release of the new machine (default 12)
  --cache DIR         cached root (default \$SDI_FRESH_CACHE or
                      /var/tmp/sdi-fresh-root-RELEASE)
  --logs DIR          logs; each run gets a subdirectory (default $LOGS)
  --rebuild           debootstrap the cached root again
  --mirror URL        Debian mirror (default: the one this machine's apt uses)
  --as-root           run the README commands as root, not as a new normal user
  --runtime-dir       give the user /run/user/UID as XDG_RUNTIME_DIR, as a
                      logind session would (default: none)
  --tests-anyway      run command 2 even when command 1 did not build
  --no-fail-fast      append --no-fail-fast to command 2 (every failing test
                      binary in one run; the README's command stops at the first)
  --exact-env         run the tests without RUST_TEST_NOCAPTURE=1 (skip
                      messages of passing tests are then not shown)
  --build-timeout MIN main job build (default $BUILD_TIMEOUT_MIN)
  --test-timeout MIN  whole test command (default $TEST_TIMEOUT_MIN)
  --up-secs N         how long the main job must stay up (default $UP_SECS)
  --keep              keep this run's root (overlay/copy) for inspection
EOF
}

while [ $# -gt 0 ]; do
    case $1 in
        --repo) REPO=$2; shift ;;
        --ref) REF=$2; shift ;;
        --release) RELEASE=$2; shift ;;
        --cache) CACHE=$2; shift ;;
        --logs) LOGS=$2; shift ;;
        --mirror) MIRROR=$2; shift ;;
        --rebuild) REBUILD=1 ;;
        --keep) KEEP=1 ;;
        --as-root) AS_ROOT=1 ;;
        --runtime-dir) RUNTIME_DIR=1 ;;
        --tests-anyway) TESTS_ANYWAY=1 ;;
        --no-fail-fast) NO_FAIL_FAST=1 ;;
        --exact-env) EXACT_ENV=1 ;;
        --build-timeout) BUILD_TIMEOUT_MIN=$2; shift ;;
        --test-timeout) TEST_TIMEOUT_MIN=$2; shift ;;
        --up-secs) UP_SECS=$2; shift ;;
        -h|--help) usage; exit 0 ;;
        *) echo "run.sh: unknown argument $1" >&2; usage >&2; exit 2 ;;
    esac
    shift
done

case $RELEASE in
    12) SUITE=bookworm ;;
    13) SUITE=trixie ;;
    *) echo "run.sh: --release takes 12 or 13" >&2; exit 2 ;;
esac
[ -n "$CACHE" ] || CACHE=${SDI_FRESH_CACHE:-/var/tmp/sdi-fresh-root-$RELEASE}
[ "$(id -u)" = 0 ] || { echo "run.sh: run as root (debootstrap, mounts, chroot)" >&2; exit 2; }
[ -n "$REPO" ] || REPO=$(git -C "$SCRIPT_DIR" rev-parse --show-toplevel)
REPO=$(cd "$REPO" && pwd)
SHA=$(git -C "$REPO" rev-parse --verify "$REF^{commit}") || { echo "run.sh: no revision $REF in $REPO" >&2; exit 2; }
SHORT=${SHA:0:9}

RUN_ID=$(date +%Y%m%d-%H%M%S)-$SHORT
LOGDIR=$LOGS/$RUN_ID
mkdir -p "$LOGDIR"
ln -sfn "$RUN_ID" "$LOGS/latest"
SETUP_LOG=$LOGDIR/setup.log
MAIN_LOG=$LOGDIR/main-job.log
TEST_LOG=$LOGDIR/tests.log
SUMMARY=$LOGDIR/summary.txt

STEP=start
step() { STEP=$*; echo "== $(date +%T) $STEP"; echo "== $(date +%T) $STEP" >>"$SETUP_LOG"; }
trap 'rc=$?; echo "run.sh: step \"$STEP\" failed at line $LINENO (exit $rc): $BASH_COMMAND (logs: $LOGDIR)" >&2; exit $rc' ERR

fmt_secs() { local s=$1; printf '%dm %02ds' $((s / 60)) $((s % 60)); }

echo "run.sh: $REPO at $REF ($SHA); logs in $LOGDIR"

# ---------------------------------------------------------------- cleanup
WORK=
ROOT=
MOUNTS=()
MAIN_PID=
BG_PID=

# Runs `timeout SECS CMD...` in the background and waits for it, so that a
# signal to this script is acted on at once (cleanup stops the command).
run_timed() {
    local secs=$1 rc=0
    shift
    timeout -k 60 "$secs" "$@" &
    BG_PID=$!
    wait "$BG_PID" || rc=$?
    BG_PID=
    return $rc
}

# Unmounts everything at or below DIR, deepest first.
umount_under() {
    awk -v d="$1" '$2 == d || index($2, d "/") == 1 { print $2 }' /proc/self/mounts | sort -r \
        | while read -r m; do umount "$m" 2>/dev/null || umount -l "$m"; done
}

# Every process whose root directory is this run's root (the chroot's).
root_pids() {
    [ -n "$ROOT" ] || return 0
    local p r
    for p in /proc/[0-9]*; do
        r=$(readlink "$p/root" 2>/dev/null) || continue
        [ "$r" = "$ROOT" ] && echo "${p#/proc/}"
    done
    return 0
}

kill_root_procs() {
    local pids
    pids=$(root_pids)
    [ -n "$pids" ] || return 0
    # shellcheck disable=SC2086
    kill -TERM $pids 2>/dev/null || true
    for _ in 1 2 3 4 5; do
        sleep 1
        pids=$(root_pids)
        [ -n "$pids" ] || return 0
    done
    # shellcheck disable=SC2086
    kill -KILL $pids 2>/dev/null || true
    sleep 1
}

cleanup() {
    local rc=$?
    trap - ERR
    set +e
    if [ -n "$MAIN_PID" ] && kill -0 "$MAIN_PID" 2>/dev/null; then
        kill -KILL -- "-$MAIN_PID" 2>/dev/null
    fi
    if [ -n "$BG_PID" ] && kill -0 "$BG_PID" 2>/dev/null; then
        kill -TERM "$BG_PID" 2>/dev/null; sleep 2
        kill -KILL -- "-$BG_PID" 2>/dev/null
    fi
    kill_root_procs
    local i
    for ((i = ${#MOUNTS[@]} - 1; i >= 0; i--)); do
        umount "${MOUNTS[i]}" 2>/dev/null || umount -l "${MOUNTS[i]}" 2>/dev/null \
            || echo "run.sh: could not unmount ${MOUNTS[i]}" >&2
    done
    [ -z "$WORK" ] || umount_under "$WORK"
    umount_under "$CACHE/root.new"
    if [ -n "$WORK" ] && [ -d "$WORK" ]; then
        if grep -qF " $WORK" /proc/self/mounts; then
            echo "run.sh: something is still mounted under $WORK; not removing it" >&2
        elif [ "$KEEP" = 1 ]; then
            echo "run.sh: kept this run's root: $WORK (rm -rf it when done)"
        else
            rm -rf "$WORK"
        fi
    fi
    exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# ---------------------------------------------------------------- cached root
apt_mirror() {
    apt-get indextargets --format '$(REPO_URI)' | sort -u \
        | awk '/\/debian\/?$/ && !/security/ { print; exit }'
}

step "cached Debian $RELEASE root ($CACHE)"
if ! command -v debootstrap >/dev/null; then
    echo "installing debootstrap"
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq debootstrap >>"$SETUP_LOG" 2>&1 || {
        apt-get update -qq >>"$SETUP_LOG" 2>&1
        DEBIAN_FRONTEND=noninteractive apt-get install -y -qq debootstrap >>"$SETUP_LOG" 2>&1
    }
fi
[ -n "$MIRROR" ] || MIRROR=$(apt_mirror)
[ -n "$MIRROR" ] || { echo "run.sh: no Debian mirror among apt's sources (apt-get indextargets); pass --mirror" >&2; exit 1; }
ARCH=$(dpkg --print-architecture)
KEY="debootstrap --variant=minbase --include=$INCLUDE --arch=$ARCH $SUITE $MIRROR"
mkdir -p "$CACHE"
exec 9>"$CACHE/lock"   # (closed for the commands run in the root: 9>&-)
flock -x -w 3600 9   # exclusive while checking/building; shared while in use
ROOT_NOTE=
if [ "$REBUILD" = 0 ] && [ -d "$CACHE/root" ] && [ "$(head -1 "$CACHE/stamp" 2>/dev/null || true)" = "$KEY" ]; then
    ROOT_NOTE="reused ($(sed -n 2p "$CACHE/stamp"))"
    echo "reusing $CACHE/root: $(sed -n 2p "$CACHE/stamp")"
else
    echo "debootstrap: $KEY (log $LOGDIR/debootstrap.log)"
    umount_under "$CACHE/root.new"
    rm -rf "$CACHE/root" "$CACHE/root.new" "$CACHE/stamp"
    t0=$(date +%s)
    if ! run_timed $((DEBOOTSTRAP_TIMEOUT_MIN * 60)) debootstrap --variant=minbase --include="$INCLUDE" \
            --arch="$ARCH" "$SUITE" "$CACHE/root.new" "$MIRROR" >"$LOGDIR/debootstrap.log" 2>&1; then
        echo "run.sh: debootstrap failed; end of its log:" >&2
        tail -30 "$LOGDIR/debootstrap.log" >&2
        tail -30 "$CACHE/root.new/debootstrap/debootstrap.log" 2>/dev/null >&2
        umount_under "$CACHE/root.new"
        rm -rf "$CACHE/root.new"
        exit 1
    fi
    chroot "$CACHE/root.new" apt-get clean
    mv "$CACHE/root.new" "$CACHE/root"
    took=$(( $(date +%s) - t0 ))
    printf '%s\nbuilt %s, debootstrap took %s\n' "$KEY" "$(date -Is)" "$(fmt_secs "$took")" >"$CACHE/stamp"
    ROOT_NOTE="built now, debootstrap took $(fmt_secs "$took")"
    echo "debootstrap took $(fmt_secs "$took")"
fi
flock -s 9
for pkg in libpipewire-0.3-dev libspa-0.2-dev clang libclang-dev libusb-1.0-0-dev pkg-config qemu-system-x86 ffmpeg; do
    if chroot "$CACHE/root" dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q 'ok installed'; then
        echo "run.sh: $pkg is installed in the cached root; it must not be (--rebuild)" >&2
        exit 1
    fi
done

# ---------------------------------------------------------------- this run's root
step "this run's root (overlay over the cached one)"
WORK=$(mktemp -d /var/tmp/sdi-fresh-run.XXXXXX)
ROOT=$WORK/root
mkdir -p "$WORK/upper" "$WORK/work" "$ROOT"
if mount -t overlay sdi-fresh -o "lowerdir=$CACHE/root,upperdir=$WORK/upper,workdir=$WORK/work" "$ROOT" 2>>"$SETUP_LOG"; then
    MOUNTS+=("$ROOT")
    echo "overlay: $ROOT"
else
    echo "overlayfs unavailable; copying the cached root"
    cp -a "$CACHE/root/." "$ROOT/"
fi
for m in proc sys dev dev/pts dev/shm; do
    mount --bind "/$m" "$ROOT/$m"
    MOUNTS+=("$ROOT/$m")
    mount --make-private "$ROOT/$m"
done
# This machine's resolver and CA bundle (it may reach crates.io through a
# proxy whose CA only this machine's bundle has).
rm -f "$ROOT/etc/resolv.conf"
cat /etc/resolv.conf >"$ROOT/etc/resolv.conf"
# (Replaced, not copied over: its entries are symlinks with absolute targets,
# which outside the chroot point at this machine's files.)
rm -rf "$ROOT/etc/ssl/certs"
mkdir -p "$ROOT/etc/ssl/certs"
cp -aL /etc/ssl/certs/. "$ROOT/etc/ssl/certs/"

if [ "$AS_ROOT" = 1 ]; then
    RUSER=root; RUID=0; RGID=0; RHOME=/root
    RPATH=/root/.cargo/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
else
    RUSER=user; RUID=1000; RGID=1000; RHOME=/home/user
    chroot "$ROOT" useradd -m -u "$RUID" -U -s /bin/bash "$RUSER"
    RPATH=$RHOME/.cargo/bin:/usr/local/bin:/usr/bin:/bin
fi

step "Rust toolchain"
HOST_RUSTUP_HOME=${RUSTUP_HOME:-$HOME/.rustup}
HOST_CARGO_HOME=${CARGO_HOME:-$HOME/.cargo}
RUSTUP_BIN=$HOST_CARGO_HOME/bin/rustup
[ -x "$RUSTUP_BIN" ] || RUSTUP_BIN=$(command -v rustup) || { echo "run.sh: no rustup on this machine" >&2; exit 1; }
TOOLCHAIN=$(cd / && env -u RUSTUP_TOOLCHAIN "$RUSTUP_BIN" default | awk '{print $1; exit}')
TC_DIR=$(realpath "$HOST_RUSTUP_HOME/toolchains/$TOOLCHAIN")
[ -x "$TC_DIR/bin/cargo" ] || { echo "run.sh: no cargo in $TC_DIR" >&2; exit 1; }
mkdir -p "$ROOT$RHOME/.rustup/toolchains" "$ROOT$RHOME/.cargo/bin"
cp -a "$TC_DIR" "$ROOT$RHOME/.rustup/toolchains/$TOOLCHAIN"
settings_version=$(awk -F'"' '/^version/ {print $2; exit}' "$HOST_RUSTUP_HOME/settings.toml" 2>/dev/null || true)
printf 'version = "%s"\ndefault_toolchain = "%s"\nprofile = "default"\nauto_self_update = "disable"\n' \
    "${settings_version:-12}" "$TOOLCHAIN" >"$ROOT$RHOME/.rustup/settings.toml"
# rustup and its proxies (cargo, rustc, ...): not other programs installed
# with cargo install, which a new user does not have.
rustup_real=$(realpath "$RUSTUP_BIN")
skipped_bins=()
for f in "$(dirname "$RUSTUP_BIN")"/*; do
    if [ "$f" -ef "$rustup_real" ] && [ "$(basename "$f")" = rustup ]; then
        cp "$f" "$ROOT$RHOME/.cargo/bin/rustup"
    elif [ "$f" -ef "$rustup_real" ]; then
        ln -s rustup "$ROOT$RHOME/.cargo/bin/$(basename "$f")"
    else
        skipped_bins+=("$(basename "$f")")
    fi
done
[ ${#skipped_bins[@]} = 0 ] || echo "not copied from $(dirname "$RUSTUP_BIN") (not rustup proxies): ${skipped_bins[*]}"
chroot "$ROOT" chown -R "$RUID:$RGID" "$RHOME"

# Runs a command in the root as the user, with a clean environment; extra
# VAR=value words may come before the command.
RENV=(PATH="$RPATH" HOME="$RHOME" USER="$RUSER" LOGNAME="$RUSER" LANG=C.UTF-8 SHELL=/bin/bash)
if [ "$RUNTIME_DIR" = 1 ]; then
    mkdir -p "$ROOT/run/user/$RUID"
    chown "$RUID:$RGID" "$ROOT/run/user/$RUID"; chmod 700 "$ROOT/run/user/$RUID"
    RENV+=(XDG_RUNTIME_DIR="/run/user/$RUID")
fi
CHROOT=(chroot --userspec="$RUID:$RGID" --groups="$RGID" "$ROOT" /usr/bin/env -i "${RENV[@]}")

"${CHROOT[@]}" /bin/bash -c 'cd && cargo --version && rustc --version && cc --version | head -1' >>"$SETUP_LOG" 2>&1 \
    || { echo "run.sh: the toolchain does not run in the root:" >&2; tail -20 "$SETUP_LOG" >&2; exit 1; }
RUSTC_VERSION=$("${CHROOT[@]}" rustc --version)
echo "toolchain $TOOLCHAIN ($RUSTC_VERSION); CARGO_HOME $RHOME/.cargo has only bin/"

step "clone $REF into $RHOME/sdi"
git clone -q --no-hardlinks "$REPO" "$ROOT$RHOME/sdi" >>"$SETUP_LOG" 2>&1
if ! git -C "$ROOT$RHOME/sdi" checkout -q --detach "$SHA" 2>>"$SETUP_LOG"; then
    git -C "$ROOT$RHOME/sdi" fetch -q "$REPO" "$SHA" >>"$SETUP_LOG" 2>&1
    git -C "$ROOT$RHOME/sdi" checkout -q --detach "$SHA"
fi
chroot "$ROOT" chown -R "$RUID:$RGID" "$RHOME/sdi"
"${CHROOT[@]}" git -C "$RHOME/sdi" log -1 --format='checked out %h %s' | tee -a "$SETUP_LOG"

# ---------------------------------------------------------------- the README's commands
step "the README's commands"
# The first two ```sh blocks under the "## Set-up" heading (up to the next
# "## " heading); blank and comment-only lines dropped.
readme_block() {
    awk -v want="$1" '
        /^##[[:space:]]+Set-?up/ { s = 1; next }
        s && /^##[[:space:]]/ { exit }
        s && !inb && /^```(sh|bash|shell|console)?[[:space:]]*$/ { inb = 1; n++; next }
        inb && /^```/ { inb = 0; if (n >= want) exit; next }
        inb && n == want && !/^[[:space:]]*(#|$)/ { print }
    ' "$ROOT$RHOME/sdi/README.md"
}
CMD1=$(readme_block 1)
CMD2=$(readme_block 2)
if [ -z "$CMD1" ] || [ -z "$CMD2" ]; then
    echo "run.sh: README.md has no two \`\`\`sh blocks under its \"## Set-up\" heading" >&2
    exit 1
fi
printf '%s\n' "$CMD1" >"$LOGDIR/command-1.sh"
printf '%s\n' "$CMD2" >"$LOGDIR/command-2.sh"
echo "command 1 (main job): $CMD1"
echo "command 2 (tests):    $CMD2"
case $CMD1 in *sdid*) ;; *) echo "run.sh: warning: command 1 does not mention sdid" ;; esac
case $CMD2 in *test*) ;; *) echo "run.sh: warning: command 2 does not mention test" ;; esac

# ---------------------------------------------------------------- command 1
step "command 1: build and run the main job (timeout ${BUILD_TIMEOUT_MIN} min for the build)"
M_BUILD=no; M_BUILD_TIME=; M_BUILD_NOTE=; M_UP=no; M_Y4M=no; M_Y4M_NOTE=; M_STOP=; M_FAIL=
M_SURVIVED_READER=
# stdout to a file, not a pipe: sdid streams y4m to stdout when it is a pipe.
# A background job of a script ignores SIGINT; env --default-signal undoes that
# so the job stops on SIGINT as it would on Ctrl-C.
t0=$(date +%s)
env --default-signal=INT,QUIT setsid nice -n 10 "${CHROOT[@]}" /bin/bash -c "cd ~/sdi && $CMD1" \
    </dev/null >"$MAIN_LOG" 2>&1 9>&- &
MAIN_PID=$!
main_alive() { kill -0 "$MAIN_PID" 2>/dev/null; }
sdid_running() { pgrep -s "$MAIN_PID" -x sdid >/dev/null 2>&1; }
# Why a build failed: cargo's error lines and the first lines a failed build
# script printed on stderr (e.g. libspa-sys: pkg-config or a library missing).
build_error() {
    { grep -aE 'failed to run custom build command for|^error: could not compile|^error(\[E[0-9]+\])?: ' "$1" | head -3
      awk '/--- stderr/ { s = 1; next } s && NF && !/^ *(note|warning): / { print; if (++n == 3) exit }' "$1"
    } | sed 's/^ *//' | cut -c1-240 | awk '!seen[$0]++' | head -6 || true
}
last_progress=$t0
while :; do
    now=$(date +%s)
    if sdid_running || grep -aq 'Running `' "$MAIN_LOG"; then
        M_BUILD=yes; M_BUILD_TIME=$((now - t0))
        M_BUILD_NOTE=$(grep -a -m1 'Finished `' "$MAIN_LOG" | sed 's/^ *//' || true)
        break
    fi
    if ! main_alive; then
        rc=0; wait "$MAIN_PID" || rc=$?
        MAIN_PID=
        M_BUILD=FAILED; M_BUILD_TIME=$((now - t0))
        M_FAIL="command 1 exited (status $rc) after $(fmt_secs $M_BUILD_TIME) before sdid ran"
        M_BUILD_NOTE=$(build_error "$MAIN_LOG")
        break
    fi
    if [ $((now - t0)) -ge $((BUILD_TIMEOUT_MIN * 60)) ]; then
        M_BUILD=TIMEOUT; M_BUILD_TIME=$((now - t0))
        M_FAIL="the build did not finish in $BUILD_TIMEOUT_MIN min"
        break
    fi
    if [ $((now - last_progress)) -ge 60 ]; then
        last_progress=$now
        echo "   $(fmt_secs $((now - t0))): $(grep -aE '^ *(Compiling|Downloaded|Updating|Locking|Building)' "$MAIN_LOG" | tail -1 | sed 's/^ *//' || true)"
    fi
    sleep 2
done

if [ "$M_BUILD" = yes ]; then
    echo "built in $(fmt_secs "$M_BUILD_TIME") (${M_BUILD_NOTE:-no Finished line})"
    [ -x "$ROOT$RHOME/sdi/target/release/sdid" ] || echo "run.sh: warning: no $RHOME/sdi/target/release/sdid"
    # stays up
    up=0
    while [ $up -lt "$UP_SECS" ]; do
        sleep 1
        sdid_running || break
        up=$((up + 1))
    done
    if [ $up -ge "$UP_SECS" ]; then
        M_UP=yes
    else
        M_UP=no; M_FAIL="sdid died $up s after the build"
    fi
    # publishes frames
    fifo=
    for _ in $(seq "$FRAME_WAIT_SECS"); do
        # sdid's first screen: "  view:    ffplay PATH"
        fifo=$(sed -n 's/^ *view: *ffplay \(.*\)$/\1/p' "$MAIN_LOG" | tail -1)
        [ -n "$fifo" ] && break
        sdid_running || break
        sleep 1
    done
    if [ -z "$fifo" ]; then
        M_Y4M_NOTE="sdid announced no y4m stream (\"view:    ffplay PATH\" on its first screen)"
    elif [ ! -p "$ROOT$fifo" ]; then
        M_Y4M_NOTE="$fifo (in the root) is not a FIFO"
    else
        timeout 20 head -c 256 "$ROOT$fifo" >"$LOGDIR/y4m-head.bin" 2>/dev/null || true
        if [ "$(head -c 9 "$LOGDIR/y4m-head.bin")" = YUV4MPEG2 ]; then
            M_Y4M=yes
            M_Y4M_NOTE="$fifo: $(head -1 "$LOGDIR/y4m-head.bin" | tr -cd '[:print:]')"
        else
            M_Y4M_NOTE="$fifo: read $(stat -c %s "$LOGDIR/y4m-head.bin") bytes in 20 s, not starting with YUV4MPEG2"
        fi
    fi
    [ "$M_Y4M" = yes ] || M_FAIL=${M_FAIL:-"no y4m frames: $M_Y4M_NOTE"}
    sleep 2
    if sdid_running; then M_SURVIVED_READER=yes; else M_SURVIVED_READER=no; M_FAIL=${M_FAIL:-"sdid died after the reader closed the FIFO"}; fi
fi

if [ -n "$MAIN_PID" ]; then
    # stop it as Ctrl-C would: SIGINT to its process group, SIGKILL after 20 s
    kill -INT -- "-$MAIN_PID" 2>/dev/null || true
    for _ in $(seq 20); do main_alive || break; sleep 1; done
    if main_alive; then
        kill -KILL -- "-$MAIN_PID" 2>/dev/null || true
        M_STOP="did not stop on SIGINT in 20 s; killed"
    fi
    rc=0; wait "$MAIN_PID" || rc=$?
    MAIN_PID=
    sleep 1
    M_STOP=${M_STOP:-"stopped on SIGINT (exit status $rc)"}
    left=$(root_pids | tr '\n' ' ')
    [ -z "$left" ] || M_STOP="$M_STOP; processes left in the root: $left(killed)"
fi
kill_root_procs
echo "main job: build $M_BUILD; up ${UP_SECS} s: $M_UP; y4m: $M_Y4M${M_STOP:+; $M_STOP}"
if [ -n "$M_FAIL" ]; then
    echo "run.sh: command 1 FAILED: $M_FAIL"
    echo "---- end of $MAIN_LOG"
    tail -40 "$MAIN_LOG"
    echo "----"
fi

# ---------------------------------------------------------------- command 2
T_RAN=no; T_RC=; T_TIME=; T_BUILD_NOTE=; T_COUNTS=; T_SKIPS=; T_FAILED=; T_PKGS=
if [ "$M_BUILD" = yes ] || [ "$TESTS_ANYWAY" = 1 ]; then
    step "command 2: the tests (timeout ${TEST_TIMEOUT_MIN} min)"
    TENV=()
    [ "$EXACT_ENV" = 1 ] || TENV=(RUST_TEST_NOCAPTURE=1)
    T_RAN=yes
    [ "${NO_FAIL_FAST:-0}" = 1 ] && CMD2="$CMD2 --no-fail-fast"
    t0=$(date +%s)
    T_RC=0
    run_timed $((TEST_TIMEOUT_MIN * 60)) env --default-signal=INT,QUIT nice -n 10 \
        "${CHROOT[@]}" "${TENV[@]}" /bin/bash -c "cd ~/sdi && $CMD2" \
        </dev/null >"$TEST_LOG" 2>&1 9>&- || T_RC=$?
    T_TIME=$(( $(date +%s) - t0 ))
    kill_root_procs
    [ "$T_RC" != 124 ] || echo "run.sh: the tests did not finish in $TEST_TIMEOUT_MIN min"
    T_BUILD_NOTE=$(grep -a -m1 'Finished `' "$TEST_LOG" | sed 's/^ *//' || true)
    T_COUNTS=$(grep -aE '^test result:' "$TEST_LOG" \
        | sed -E 's/.* ([0-9]+) passed; ([0-9]+) failed; ([0-9]+) ignored.*/\1 \2 \3/' \
        | awk '{p += $1; f += $2; i += $3; n++} END {printf "%d passed, %d failed, %d ignored (%d test binaries)", p, f, i, n}' || true)
    T_FAILED=$( { grep -aE '^test .* \.\.\. FAILED$|^error: test failed' "$TEST_LOG"; build_error "$TEST_LOG"; } | awk '!seen[$0]++' || true)
    # Each skip line with the test binary that printed it (the last
    # "Running ..." header before it) and how often it came.
    T_SKIPS=$(awk '
        /^ *Running / {
            bin = $0; sub(/^ *Running /, "", bin)
            exe = bin; sub(/^.*deps\//, "", exe); sub(/-[0-9a-f]+\)$/, "", exe)
            sub(/ \(.*$/, "", bin); bin = bin " in " exe; next
        }
        /^ *Doc-tests / { bin = $0; sub(/^ *Doc-tests /, "doc-tests ", bin); next }
        /^test result:/ { bin = "after " bin; next }
        tolower($0) ~ /skip/ { line = $0; sub(/^test .* \.\.\. /, "", line); print "[" bin "] " substr(line, 1, 220) }
    ' "$TEST_LOG" | sort | uniq -c | sort -rn || true)
    T_PKGS=$(grep -ai 'skip' "$TEST_LOG" | grep -oE 'apt(-get)? install [a-z0-9.+ -]+' \
        | sed -E 's/apt(-get)? install //' | tr ' ' '\n' | grep -v '^$' | sort -u | tr '\n' ' ' || true)
    echo "tests: exit $T_RC after $(fmt_secs "$T_TIME"); $T_COUNTS"
    if [ "$T_RC" != 0 ]; then
        echo "---- end of $TEST_LOG"
        tail -40 "$TEST_LOG"
        echo "----"
    fi
fi

# ---------------------------------------------------------------- summary
OK=1
[ "$M_BUILD" = yes ] && [ "$M_UP" = yes ] && [ "$M_Y4M" = yes ] && [ "$M_SURVIVED_READER" = yes ] || OK=0
[ "$T_RAN" = yes ] && [ "$T_RC" = 0 ] || OK=0
{
    echo "== fresh machine: $REPO at $REF ($SHORT), $(date -Is)"
    echo "root:      Debian $RELEASE ($SUITE) minbase + $INCLUDE from $MIRROR; $ROOT_NOTE"
    if [ "$AS_ROOT" = 1 ]; then who="root, $RHOME/sdi"; else who="normal user '$RUSER' (uid $RUID), $RHOME/sdi"; fi
    echo "as:        $who; env -i PATH HOME USER LANG=C.UTF-8; $([ "$RUNTIME_DIR" = 1 ] && echo "XDG_RUNTIME_DIR=/run/user/$RUID" || echo "no XDG_RUNTIME_DIR"); no session bus"
    echo "toolchain: $TOOLCHAIN ($RUSTC_VERSION), empty CARGO_HOME"
    echo "command 1: $CMD1"
    echo "  build:   $M_BUILD after $(fmt_secs "${M_BUILD_TIME:-0}")"
    [ -z "$M_BUILD_NOTE" ] || printf '%s\n' "$M_BUILD_NOTE" | sed 's/^/           /'
    echo "  up ${UP_SECS} s:  $M_UP"
    echo "  y4m:     $M_Y4M${M_Y4M_NOTE:+ ($M_Y4M_NOTE)}"
    [ -z "$M_SURVIVED_READER" ] || echo "  alive after the reader left: $M_SURVIVED_READER"
    [ -z "$M_STOP" ] || echo "  stop:    $M_STOP"
    [ -z "$M_FAIL" ] || echo "  FAILED:  $M_FAIL"
    echo "command 2: $CMD2"
    if [ "$T_RAN" = yes ]; then
        echo "  exit:    $T_RC after $(fmt_secs "$T_TIME")${T_BUILD_NOTE:+ (build: $T_BUILD_NOTE)}$([ "$EXACT_ENV" = 1 ] || echo "; ran with RUST_TEST_NOCAPTURE=1")"
        echo "  counts:  $T_COUNTS"
        [ -z "$T_FAILED" ] || { echo "  failures:"; printf '%s\n' "$T_FAILED" | sed 's/^/    /' | head -40; }
        if [ -n "$T_SKIPS" ]; then
            echo "  skips (count, [test binary] line):"
            printf '%s\n' "$T_SKIPS" | sed 's/^/  /'
            [ -z "$T_PKGS" ] || echo "  packages the skips name: $T_PKGS"
        else
            echo "  skips:   none printed$(grep -aqE '^test result:' "$TEST_LOG" || echo " (no test ran)")"
        fi
    else
        echo "  not run: command 1 did not build (--tests-anyway runs it regardless)"
    fi
    echo "logs:      $LOGDIR"
    [ "$OK" = 1 ] && echo "RESULT: PASS" || echo "RESULT: FAIL"
} | tee "$SUMMARY"
[ "$OK" = 1 ] && exit 0
exit 1
