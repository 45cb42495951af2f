#!/usr/bin/env bash
# arm_check.sh: install and run lite_vo on arm64 (aarch64) under emulation and compare with this machine.
#
# Reproduces the ARM check from nothing on an x86-64 Debian/Ubuntu machine with root:
#   1. installs qemu-user-static, binfmt-support and debootstrap from the distribution if missing,
#   2. creates an arm64 Debian bookworm root with debootstrap in a cache folder it reuses
#      (${XDG_CACHE_HOME:-~/.cache}/lite_vo/arm64-bookworm; the Debian mirror is the one apt uses here),
#   3. installs the project from a copy of this checkout into a fresh venv there with `pip install .`
#      (what a Raspberry Pi OS / Jetson user does), runs `lite-vo warmup` and
#      `lite-vo run SEQ --init depth --mode sync --max-frames N`,
#   4. does the same on the host, and
#   5. writes DIR/report.md (tools/arm_report.py): versions, wheel or source for each package, time per
#      step, difference between the two trajectories in mm and deg.
# Emulated steps run under `nice -n 19`. Exits non-zero when a step fails, naming the step and its log.
#
# Usage: tools/arm_check.sh --out DIR [--frames N] [--seq PATH] [--ar] [--ar-only] [--ar-minutes M]
#                           [--mirror URL] [--root PATH] [--tol-mm X] [--tol-deg X]
#   --ar          also try the [ar] extra in the arm64 root: aarch64 wheels of pybullet/moderngl/glcontext/
#                 trimesh, the system packages a source build needs, moderngl from source, and a
#                 pybullet source build limited to --ar-minutes (default 45) with its progress (object
#                 files compiled of the ones its setup.py lists) recorded every minute; `lite-vo demo
#                 --frames 10` when everything installed.
#   --ar-only     only the AR steps (skips warm-up/run on both sides; the root and venv are set up).
# Takes tens of minutes (the emulated numba compile alone is several minutes); not part of the tests.
set -u -o pipefail

usage() { sed -n '2,/^set -u/p' "$0" | sed '$d; s/^# \{0,1\}//'; }

OUT="" FRAMES=30 AR=0 AR_ONLY=0 AR_MINUTES=45 MIRROR="" TOL_MM=1.0 TOL_DEG=0.1
REPO="$(cd "$(dirname "$0")/.." && pwd)"
SEQ="$REPO/../shared/data/icl_livingroom_211"
CACHE="${XDG_CACHE_HOME:-$HOME/.cache}/lite_vo"
ROOT=""
while [ $# -gt 0 ]; do
    case "$1" in
        --out) OUT="$2"; shift 2 ;;
        --frames) FRAMES="$2"; shift 2 ;;
        --seq) SEQ="$2"; shift 2 ;;
        --ar) AR=1; shift ;;
        --ar-only) AR=1; AR_ONLY=1; shift ;;
        --ar-minutes) AR_MINUTES="$2"; shift 2 ;;
        --mirror) MIRROR="$2"; shift 2 ;;
        --root) ROOT="$2"; shift 2 ;;
        --tol-mm) TOL_MM="$2"; shift 2 ;;
        --tol-deg) TOL_DEG="$2"; shift 2 ;;
        -h|--help) usage; exit 0 ;;
        *) echo "arm_check: unknown argument '$1' (see --help)" >&2; exit 2 ;;
    esac
done
[ -n "$OUT" ] || { echo "arm_check: --out DIR is required (see --help)" >&2; exit 2; }
[ "$(id -u)" = 0 ] || { echo "arm_check: needs root (apt-get, debootstrap, chroot, mount)" >&2; exit 2; }
[ -f "$SEQ/rgb.txt" ] || { echo "arm_check: sequence not found: $SEQ (give --seq PATH)" >&2; exit 2; }
case "$FRAMES" in ''|*[!0-9]*) echo "arm_check: --frames must be a positive integer" >&2; exit 2 ;; esac
ROOT="${ROOT:-$CACHE/arm64-bookworm}"
SEQ="$(cd "$SEQ" && pwd)"
mkdir -p "$OUT/logs" "$OUT/aarch64" "$OUT/host" "$CACHE"
OUT="$(cd "$OUT" && pwd)"
STEPS="$OUT/steps.tsv"
printf 'side\tstep\tseconds\tstatus\n' > "$STEPS"
: > "$OUT/failed_steps.txt"
PY_HOST="${PYTHON:-python3}"
CHROOT_PATH=/opt/lite_vo/venv/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin

# ---------------------------------------------------------------------------------------------------
# step SIDE NAME [--soft] CMD...: run CMD with its output in logs/SIDE-NAME.log, record the time.
# A failing step stops the script (exit 1) unless --soft (then it is recorded and the script fails at
# the end, after the report).
step() {
    local side="$1" name="$2" soft=0; shift 2
    if [ "${1:-}" = "--soft" ]; then soft=1; shift; fi
    local log="$OUT/logs/$side-$name.log" t0 t1 dt rc
    echo "[$(date +%H:%M:%S)] $side: $name" >&2
    t0=$(date +%s.%N)
    "$@" > "$log" 2>&1
    rc=$?
    t1=$(date +%s.%N)
    dt=$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.1f", b - a }')
    if [ $rc = 0 ]; then status=ok; elif [ $rc = 124 ]; then status="timeout"; else status="exit $rc"; fi
    printf '%s\t%s\t%s\t%s\n' "$side" "$name" "$dt" "$status" >> "$STEPS"
    if [ $rc != 0 ]; then
        echo "arm_check: step '$side: $name' failed ($status) after ${dt} s; log: $log" >&2
        tail -n 15 "$log" | sed 's/^/    /' >&2
        echo "$side: $name ($status, log logs/$side-$name.log)" >> "$OUT/failed_steps.txt"
        [ $soft = 1 ] || exit 1
    fi
    return $rc
}

# in_root CMD...: run CMD in the arm64 root, emulated, at the lowest priority, with a clean environment.
in_root() {
    nice -n 19 chroot "$ROOT" /usr/bin/env -i PATH="$CHROOT_PATH" HOME=/root LANG=C.UTF-8 TERM=dumb \
        DEBIAN_FRONTEND=noninteractive PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_DEFAULT_TIMEOUT=180 "$@"
}

MOUNTS=()
cleanup() {
    local i
    for ((i = ${#MOUNTS[@]} - 1; i >= 0; i--)); do umount -l "${MOUNTS[$i]}" 2>/dev/null; done
    [ -n "${MONITOR_PID:-}" ] && kill "$MONITOR_PID" 2>/dev/null
    return 0
}
trap cleanup EXIT
trap 'echo "arm_check: interrupted" >&2; exit 130' INT TERM

mount_into_root() {  # mount_into_root TYPE|--bind SRC DST [ro]
    local kind="$1" src="$2" dst="$ROOT$3"
    mkdir -p "$dst"
    mountpoint -q "$dst" && umount -l "$dst"
    if [ "$kind" = --bind ]; then mount --bind "$src" "$dst" || return 1
    else mount -t "$kind" "$src" "$dst" || return 1; fi
    MOUNTS+=("$dst")
    if [ "${4:-}" = ro ]; then mount -o remount,bind,ro "$dst" || return 1; fi
}

# ---------------------------------------------------------------------------------------------------
# Host: tools, binfmt, mirror.
host_tools() {
    local need=()
    command -v qemu-aarch64-static > /dev/null || need+=(qemu-user-static)
    command -v update-binfmts > /dev/null || need+=(binfmt-support)
    command -v debootstrap > /dev/null || need+=(debootstrap)
    if [ ${#need[@]} -gt 0 ]; then
        echo "installing: ${need[*]}"
        apt-get update && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${need[@]}" \
            || return 1
    else
        echo "already installed: qemu-user-static binfmt-support debootstrap"
    fi
    dpkg-query -W qemu-user-static binfmt-support debootstrap
}

host_binfmt() {
    if [ ! -e /proc/sys/fs/binfmt_misc/register ]; then
        mount -t binfmt_misc binfmt_misc /proc/sys/fs/binfmt_misc || return 1
    fi
    if [ ! -e /proc/sys/fs/binfmt_misc/qemu-aarch64 ]; then
        update-binfmts --import qemu-aarch64 2>/dev/null || update-binfmts --enable qemu-aarch64 || return 1
    fi
    cat /proc/sys/fs/binfmt_misc/qemu-aarch64
    grep -q '^enabled' /proc/sys/fs/binfmt_misc/qemu-aarch64
}

# The Debian mirror apt uses on this machine (one-line and deb822 sources), else deb.debian.org.
detect_mirror() {
    local url
    url=$(cat /etc/apt/sources.list /etc/apt/sources.list.d/*.list /etc/apt/sources.list.d/*.sources 2>/dev/null \
        | grep -v '^[[:space:]]*#' | grep -oE '(https?|ftp)://[^[:space:]]+' | sed 's:/*$::' \
        | grep -E '/debian$' | head -n 1)
    echo "${url:-http://deb.debian.org/debian}"
}

# ---------------------------------------------------------------------------------------------------
# The arm64 root (created once, reused).
make_root() {
    if [ -f "$ROOT/.lite_vo_root_ok" ]; then
        echo "reusing $ROOT (created $(cat "$ROOT/.lite_vo_root_ok"))"
        return 0
    fi
    local mirror="${MIRROR:-$(detect_mirror)}" tmp="$ROOT.partial"
    echo "debootstrap arm64 bookworm from $mirror into $tmp"
    rm -rf "$tmp"
    debootstrap --arch=arm64 --variant=minbase --include=python3,python3-venv,ca-certificates \
        bookworm "$tmp" "$mirror" || return 1
    rm -rf "$ROOT" && mv "$tmp" "$ROOT" && date -u +%Y-%m-%dT%H:%M:%SZ > "$ROOT/.lite_vo_root_ok"
}

# Mounts, DNS, the host's extra CA certificates (e.g. a company proxy) and the packages lite_vo needs.
prepare_root() {
    mount_into_root proc proc /proc || return 1
    mount_into_root sysfs sysfs /sys || return 1
    mount_into_root --bind /dev /dev || return 1
    mount_into_root --bind /dev/pts /dev/pts || return 1
    mount_into_root --bind "$SEQ" /mnt/seq ro || return 1
    cp -L /etc/resolv.conf "$ROOT/etc/resolv.conf" || return 1
    if ls /usr/local/share/ca-certificates/*.crt > /dev/null 2>&1; then
        mkdir -p "$ROOT/usr/local/share/ca-certificates"
        cp /usr/local/share/ca-certificates/*.crt "$ROOT/usr/local/share/ca-certificates/"
        in_root update-ca-certificates || return 1
    fi
    if ! in_root dpkg-query -W python3-venv > /dev/null 2>&1; then
        in_root apt-get update && in_root apt-get install -y --no-install-recommends python3 python3-venv \
            || return 1
    fi
    in_root uname -m
    in_root python3 -c 'import platform; print(platform.machine(), platform.python_version())'
    in_root dpkg-query -W python3 python3-venv libc6
}

# A copy of this checkout (tracked and untracked-not-ignored files: like a fresh clone plus local edits).
copy_checkout() {  # copy_checkout DEST
    local dest="$1"
    rm -rf "$dest" && mkdir -p "$dest" || return 1
    if git -C "$REPO" rev-parse --git-dir > /dev/null 2>&1; then
        (cd "$REPO" && git ls-files -z --cached --others --exclude-standard \
            | while IFS= read -r -d '' f; do [ -e "$f" ] && printf '%s\0' "$f"; done \
            | tar --null -T - -cf -) | tar -C "$dest" -xf - || return 1
        git -C "$REPO" describe --always --dirty > "$dest/.lite_vo_commit" 2>/dev/null
    else
        tar -C "$REPO" --exclude=./.venv --exclude=./.git --exclude='__pycache__' --exclude=./lite_vo_out \
            -cf - . | tar -C "$dest" -xf - || return 1
    fi
    echo "copied $(find "$dest" -type f | wc -l) files of $REPO ($(cat "$dest/.lite_vo_commit" 2>/dev/null))"
}

# ---------------------------------------------------------------------------------------------------
# The two sides. RUNNER is in_root (emulated) or host_env; paths are as the runner sees them.
host_env() { env PIP_DISABLE_PIP_VERSION_CHECK=1 PATH="$HOST_VENV/bin:$PATH" "$@"; }

side_venv() {  # side_venv RUNNER PYTHON VENV SRC REPORT
    local run="$1" py="$2" venv="$3" src="$4" report="$5"
    $run rm -rf "$venv" || return 1
    $run "$py" -m venv "$venv" || return 1
    $run "$venv/bin/python" -m pip --version
    $run "$venv/bin/python" -m pip install --report "$report" "$src" || return 1
    $run "$venv/bin/python" -m pip list
}

side_run() {  # side_run RUNNER VENV SEQ OUTDIR
    local run="$1" venv="$2" seq="$3" out="$4"
    $run rm -rf "$out"
    $run "$venv/bin/lite-vo" run "$seq" --init depth --mode sync --max-frames "$FRAMES" --out "$out" --force --quiet
}

collect() {  # collect SRC_DIR DEST_DIR FILES...
    local src="$1" dest="$2"; shift 2
    local f
    for f in "$@"; do cp "$src/$f" "$dest/$f" || return 1; done
}

host_python_info() {
    "$PY_HOST" -c 'import platform, sys; print(platform.machine(), platform.python_version(), sys.executable)'
}

# ---------------------------------------------------------------------------------------------------
# The AR extra on arm64.
ar_wheels() {  # which [ar] packages publish an aarch64 wheel for this Python (no builds)
    local p
    printf 'package\taarch64_wheel\n' > "$OUT/aarch64/ar_wheels.tsv"
    for p in pybullet trimesh moderngl glcontext; do
        rm -rf "$ROOT/tmp/arw" && mkdir -p "$ROOT/tmp/arw"
        if in_root /opt/lite_vo/venv/bin/pip download --only-binary=:all: --no-deps -d /tmp/arw "$p"; then
            printf '%s\t%s\n' "$p" "$(ls "$ROOT/tmp/arw")" >> "$OUT/aarch64/ar_wheels.tsv"
        else
            printf '%s\tnone\n' "$p" >> "$OUT/aarch64/ar_wheels.tsv"
        fi
    done
    cat "$OUT/aarch64/ar_wheels.tsv"
}

ar_apt() {  # what a source build of pybullet and moderngl/glcontext needs, plus Mesa for rendering
    in_root apt-get update || return 1
    in_root apt-get install -y --no-install-recommends build-essential python3-dev pkg-config \
        libx11-dev libgl-dev libegl-dev libegl1 libgl1-mesa-dri libegl-mesa0 || return 1
}

ar_moderngl() {  # moderngl/glcontext as pip picks them (newest: from source), then an EGL context
    in_root /opt/lite_vo/venv/bin/pip install -v moderngl trimesh || return 1
    in_root /opt/lite_vo/venv/bin/pip list
    in_root /opt/lite_vo/venv/bin/python -c 'from ar_demo.render import create_context
ctx = create_context(); print("EGL context:", ctx.info["GL_RENDERER"], ctx.info["GL_VERSION"])'
}

# pybullet from source, limited to AR_MINUTES; a monitor records how many object files exist.
ar_pybullet() {
    local prog="$OUT/aarch64/pybullet_progress.tsv" build="$ROOT/tmp/pybullet_build"
    rm -rf "$build" && mkdir -p "$build" "$ROOT/opt/lite_vo/wheels"
    printf 'minutes\tobject_files\n' > "$prog"
    (
        local m=0
        while sleep 60; do
            m=$((m + 1))
            printf '%d\t%d\n' "$m" "$(find "$build" -name '*.o' 2>/dev/null | wc -l)" >> "$prog"
        done
    ) &
    MONITOR_PID=$!
    # pybullet has no pyproject.toml: pip builds it with the venv's setuptools (numpy visible) and
    # needs the `wheel` package for that
    in_root /opt/lite_vo/venv/bin/pip install wheel || return 1
    timeout --kill-after=30 "${AR_MINUTES}m" nice -n 19 chroot "$ROOT" /usr/bin/env -i PATH="$CHROOT_PATH" \
        HOME=/root LANG=C.UTF-8 TMPDIR=/tmp/pybullet_build PIP_DISABLE_PIP_VERSION_CHECK=1 \
        /opt/lite_vo/venv/bin/pip wheel --no-deps --no-binary pybullet -v -w /opt/lite_vo/wheels pybullet
    local rc=$?
    kill "$MONITOR_PID" 2>/dev/null; wait "$MONITOR_PID" 2>/dev/null; MONITOR_PID=""
    printf 'end\t%d\n' "$(find "$build" -name '*.o' 2>/dev/null | wc -l)" >> "$prog"
    cat "$prog"
    return $rc
}

ar_demo() {
    in_root sh -c 'pip install /opt/lite_vo/wheels/pybullet-*.whl && pip install "/opt/lite_vo/src[ar]"' || return 1
    in_root sh -c 'cd /tmp && rm -rf demo && lite-vo demo --frames 10 --out /tmp/demo --quiet && ls -la /tmp/demo'
}

# ---------------------------------------------------------------------------------------------------
echo "arm_check: out=$OUT root=$ROOT seq=$SEQ frames=$FRAMES ar=$AR" >&2
{
    echo "frames=$FRAMES"; echo "sequence=$SEQ"; echo "root=$ROOT"; echo "mirror=${MIRROR:-$(detect_mirror)}"
    echo "host_kernel=$(uname -srm)"; echo "date=$(date -u +%Y-%m-%dT%H:%M:%SZ)"
    echo "commit=$(git -C "$REPO" describe --always --dirty 2>/dev/null)"
    echo "host_os=$(. /etc/os-release && echo "$PRETTY_NAME")"
} > "$OUT/check.env"

step host tools host_tools
step host binfmt host_binfmt
echo "qemu=$(dpkg-query -W -f='${Version}' qemu-user-static)" >> "$OUT/check.env"
step aarch64 debootstrap make_root
step aarch64 prepare-root prepare_root
step aarch64 copy-checkout copy_checkout "$ROOT/opt/lite_vo/src"
step aarch64 pip-install side_venv in_root python3 /opt/lite_vo/venv /opt/lite_vo/src /opt/lite_vo/pip_report.json
collect "$ROOT/opt/lite_vo" "$OUT/aarch64" pip_report.json || exit 1

if [ $AR_ONLY = 0 ]; then
    step aarch64 warmup in_root /opt/lite_vo/venv/bin/lite-vo warmup
    step aarch64 run side_run in_root /opt/lite_vo/venv /mnt/seq /opt/lite_vo/out
    collect "$ROOT/opt/lite_vo/out" "$OUT/aarch64" trajectory.txt run.json timing.json || exit 1

    HOST_WORK="$CACHE/host"
    HOST_VENV="$HOST_WORK/venv"
    step host python host_python_info
    step host copy-checkout copy_checkout "$HOST_WORK/src"
    step host pip-install side_venv host_env "$PY_HOST" "$HOST_VENV" "$HOST_WORK/src" "$HOST_WORK/pip_report.json"
    collect "$HOST_WORK" "$OUT/host" pip_report.json || exit 1
    step host warmup host_env lite-vo warmup
    step host run side_run host_env "$HOST_VENV" "$SEQ" "$HOST_WORK/out"
    collect "$HOST_WORK/out" "$OUT/host" trajectory.txt run.json timing.json || exit 1
fi

if [ $AR = 1 ]; then
    step aarch64 ar-wheels ar_wheels
    step aarch64 ar-apt --soft ar_apt
    step aarch64 ar-moderngl --soft ar_moderngl
    if step aarch64 ar-pybullet --soft ar_pybullet; then
        step aarch64 ar-demo --soft ar_demo
    fi
fi

REPORT_ARGS=(--out "$OUT" --tol-mm "$TOL_MM" --tol-deg "$TOL_DEG")
[ $AR = 1 ] && REPORT_ARGS+=(--ar --ar-minutes "$AR_MINUTES")
[ $AR_ONLY = 1 ] && REPORT_ARGS+=(--ar-only)
step host report --soft "$PY_HOST" "$REPO/tools/arm_report.py" "${REPORT_ARGS[@]}"
cat "$OUT/logs/host-report.log" >&2

if [ -s "$OUT/failed_steps.txt" ]; then
    echo "arm_check: FAILED steps:" >&2
    sed 's/^/  /' "$OUT/failed_steps.txt" >&2
    exit 1
fi
echo "arm_check: all steps ok; report: $OUT/report.md" >&2
