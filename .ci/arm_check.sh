#!/usr/bin/env bash
# `make arm-check`: the robot-side install on an emulated aarch64 CPU, its commands, and what it
# computes and says against this x86-64 host. A Debian arm64 root (bookworm: Python 3.11, as
# here) is built once with debootstrap and cached; QEMU's user mode runs it as a Cortex-A76
# (dot products, as a Pi 5, RK3588 or Jetson Orin) and a Cortex-A72 (none, as a Pi 4). For
# what an ARM build computes and whether it installs and runs, never for how fast: emulated
# vector code runs orders of magnitude slower (`make bench` on the board measures that).
#
# Per CPU model: pip installs the working tree under constraints/robot.txt into a fresh venv;
# `edge-depth demo`, `replay` (fp32 and int8) and `calibrate check` of sim recordings must
# exit 0; experiments/arm_compare.py then fails, naming it, on any difference from x86-64: the
# engine's graphs (experiments/ort_on_avx2.py's scene) and the replays' disparity beyond
# 1e-3 px (fp32) or 0.05 px mean (int8), the precision `auto` chose (int8 with dot products,
# else fp32), and the exit status and lines of four bad inputs.
#
# Settings (environment):
#   ARM_CPUS   QEMU CPU models, first to last (default "cortex-a76 cortex-a72")
#   ARM_CHECK  "full" (default) or "fast": the install and a two-frame demo on the first model
#   ARM_ROOT   the cached root (default /var/cache/edge-depth/arm64-root; built when absent)
#   ARM_OUT    where the runs write (default out/arm-check)
#   ARM_OPENVINO=1  also OpenVINO's graphs: `pip install openvino` on ARM (not in the robot-side
#              install there; `auto` takes ONNX Runtime), fp32 and int8 against x86's OpenVINO
# Needs root (chroot, binfmt_misc); installs qemu-user-static and debootstrap when missing.
set -euo pipefail
cd "$(dirname "$0")/.."
REPO=$PWD
CPUS=${ARM_CPUS:-cortex-a76 cortex-a72}
MODE=${ARM_CHECK:-full}
OPENVINO=${ARM_OPENVINO:-0}
ROOT=${ARM_ROOT:-/var/cache/edge-depth/arm64-root}
OUT=$(mkdir -p "${ARM_OUT:-out/arm-check}" && cd "${ARM_OUT:-out/arm-check}" && pwd)
SUITE=bookworm  # Debian 12: python3 3.11, the project's oldest Python
HOST_BIN=$REPO/.venv/bin
START=$SECONDS

say() { echo "arm-check [$((SECONDS - START)) s]: $*"; }

need_host_tools() {
    command -v qemu-aarch64-static > /dev/null && command -v debootstrap > /dev/null && return
    say "installing qemu-user-static and debootstrap"
    apt-get update -q > /dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q qemu-user-static debootstrap > /dev/null
}

# aarch64 programs run through QEMU by the kernel's binfmt_misc, so that the root's own
# programs (dpkg, pip's build subprocesses) start each other; the "F" flag of Debian's entry
# opens the interpreter at registration, so it runs inside the chroot too
need_binfmt() {
    local misc=/proc/sys/fs/binfmt_misc
    [ -e "$misc/register" ] || mount -t binfmt_misc binfmt_misc "$misc"
    [ -e "$misc/qemu-aarch64" ] && return
    grep '^:' /usr/lib/binfmt.d/qemu-aarch64.conf > "$misc/register"
}

# the root is built beside its final place and moved there whole: a half-built one is never
# taken for the cache
need_root() {
    if [ -f "$ROOT/.edge-depth-root" ]; then
        say "arm64 root cached at $ROOT"
    else
        say "building the arm64 root ($SUITE) at $ROOT"
        rm -rf "$ROOT.partial" && mkdir -p "$(dirname "$ROOT")"
        debootstrap --arch=arm64 --variant=minbase \
            --include=python3,python3-venv,libstdc++6,libgomp1 \
            "$SUITE" "$ROOT.partial" http://deb.debian.org/debian > "$OUT/debootstrap.log"
        mkdir -p "$ROOT.partial/out" "$ROOT.partial/src"
        echo "debootstrap $SUITE arm64" > "$ROOT.partial/.edge-depth-root"
        rm -rf "$ROOT" && mv "$ROOT.partial" "$ROOT"
    fi
    # this host's name servers and certificate authorities, for pip inside
    cp /etc/resolv.conf "$ROOT/etc/resolv.conf"
    cp /etc/ssl/certs/ca-certificates.crt "$ROOT/etc/host-ca-certificates.crt"
}

# arm CPU COMMAND...: COMMAND in the root as QEMU's CPU model CPU, in /out/inputs, with the
# working tree's copy at /src and $OUT at /out; the mounts live in a namespace of their own.
# No /sys: with it, ONNX Runtime's CPU library (pytorch/cpuinfo) reads the x86 host's
# /proc/cpuinfo that QEMU 7.2 shows, takes it for an ARM one and crashes; without it, it
# says so on stderr and takes the features from the aux vector, which are the emulated CPU's.
# OpenVINO needs /sys (without it, it crashes): `WITH_SYS=1 arm …` for its runs alone.
arm() {
    local cpu=$1
    shift
    unshare --mount --propagation private -- bash -c '
        set -e
        root=$1 out=$2 src=$3 cpu=$4 sys=$5
        shift 5
        mount --bind /proc "$root/proc"
        [ "$sys" = 1 ] && mount --rbind /sys "$root/sys"
        mount --rbind /dev "$root/dev"
        mount --bind "$out" "$root/out"
        mount --bind "$src" "$root/src"
        chroot=$(command -v chroot)
        exec env -i QEMU_CPU="$cpu" HOME=/root LANG=C.UTF-8 PATH=/opt/edge/bin:/usr/bin:/bin \
            PIP_CACHE_DIR=/var/cache/pip PIP_CERT=/etc/host-ca-certificates.crt \
            PIP_DISABLE_PIP_VERSION_CHECK=1 PYTHONDONTWRITEBYTECODE=1 \
            "$chroot" "$root" /bin/sh -c "cd /out/inputs && exec \"\$@\"" sh "$@"
    ' arm-check "$ROOT" "$OUT" "$OUT/src" "$cpu" "${WITH_SYS:-0}" "$@"
}

# the working tree as git sees it (tracked and untracked, ignored files aside), installed as
# pip installs a clone: built into a wheel on ARM, then installed with its pinned dependencies
install_in_root() {
    rm -rf "$OUT/src" && mkdir -p "$OUT/src"
    git ls-files -z -co --exclude-standard | tar --null --ignore-failed-read -T - -cf - 2> /dev/null \
        | tar -xf - -C "$OUT/src"
    say "pip install -c constraints/robot.txt . (as $1)"
    arm "$1" sh -c 'rm -rf /opt/edge && python3 -m venv /opt/edge \
        && /opt/edge/bin/pip install -q -c /src/constraints/robot.txt /src' \
        > "$OUT/install.log" 2>&1 || { tail -20 "$OUT/install.log"; say "FAIL: install"; exit 1; }
    if [ "$OPENVINO" = 1 ]; then
        arm "$1" pip install -q -c /src/constraints/robot.txt openvino >> "$OUT/install.log" 2>&1 \
            || { tail -20 "$OUT/install.log"; say "FAIL: pip install openvino"; exit 1; }
    fi
    arm "$1" python -c 'import platform, sys; print(platform.machine(), sys.version.split()[0])'
}

# host COMMAND...: COMMAND on this x86-64 host, with its .venv, in $OUT/inputs
host() { (cd "$OUT/inputs" && PATH=$HOST_BIN:$PATH "$@"); }

# bad_inputs DIR RUNNER...: the four bad inputs through RUNNER (`host` or `arm CPU`), each
# one's exit status and stderr kept as $OUT/DIR/CASE.rc and .err
bad_inputs() {
    local dir=$1 case rc args
    shift
    for case in replay-damaged check-damaged check-bad-calib replay-bad-calib; do
        case $case in
            replay-damaged) args="replay damaged.mcap" ;;
            check-damaged) args="calibrate check damaged.mcap" ;;
            check-bad-calib) args="calibrate check sim8.mcap --calib bad_calib.toml" ;;
            replay-bad-calib) args="replay sim.mcap --calib bad_calib.toml" ;;
        esac
        [[ $args == replay* ]] && args+=" --runtime onnxruntime --out ../$dir/$case.mcap"
        rc=0
        # shellcheck disable=SC2086  # args: words
        "$@" edge-depth $args > "$OUT/$dir/$case.out" 2> "$OUT/$dir/$case.err" || rc=$?
        echo "$rc" > "$OUT/$dir/$case.rc"
    done
}

# runs DIR SRC RUNNER...: what both CPUs run, into $OUT/DIR (SRC: the working tree as RUNNER
# sees it): replays of the 3-frame recording in fp32 and int8, the engine's graphs on one
# scene, the bad inputs (the demo and calibrate check, whose exit status is the verdict, run
# on ARM only)
runs() {
    local dir=$1 src=$2 precision
    shift 2
    mkdir -p "$OUT/$dir"
    for precision in fp32 int8; do
        "$@" edge-depth replay sim.mcap --runtime onnxruntime --precision "$precision" \
            --out "../$dir/replay-$precision.mcap" > "$OUT/$dir/replay-$precision.out" 2>&1 \
            || { tail -5 "$OUT/$dir/replay-$precision.out"; say "FAIL: $dir replay $precision"
                 return 1; }
    done
    "$@" python "$src/experiments/ort_on_avx2.py" run "../$dir/graphs.npz" \
        --runtimes onnxruntime > "$OUT/$dir/graphs.out" 2>&1 \
        || { tail -5 "$OUT/$dir/graphs.out"; say "FAIL: $dir graphs"; return 1; }
    if [ "$OPENVINO" = 1 ]; then
        WITH_SYS=1 "$@" python "$src/experiments/ort_on_avx2.py" run \
            "../$dir/graphs-openvino.npz" --runtimes openvino > "$OUT/$dir/graphs-openvino.out" \
            2>&1 || { tail -5 "$OUT/$dir/graphs-openvino.out"; say "FAIL: $dir OpenVINO"; return 1; }
    fi
    bad_inputs "$dir" "$@"
}

# the QEMU models with ARM's dot products (SDOT/UDOT), where `auto` must choose int8
DOTPROD_MODELS=" cortex-a76 neoverse-n1 max "

# on_model CPU: the demo, calibrate check and `runs` as QEMU's CPU, then the comparison
on_model() {
    local cpu=$1 expect=fp32
    [[ $DOTPROD_MODELS == *" $cpu "* ]] && expect=int8
    mkdir -p "$OUT/$cpu"
    say "$cpu: edge-depth demo --frames 3"
    arm "$cpu" edge-depth demo --frames 3 --out "../$cpu/demo" > "$OUT/$cpu/demo.out" 2>&1 \
        || { tail -5 "$OUT/$cpu/demo.out"; say "FAIL: $cpu demo"; return 1; }
    head -1 "$OUT/$cpu/demo.out"
    say "$cpu: edge-depth calibrate check of an 8-frame recording"
    arm "$cpu" edge-depth calibrate check sim8.mcap > "$OUT/$cpu/check.out" 2>&1 \
        || { tail -5 "$OUT/$cpu/check.out"; say "FAIL: $cpu calibrate check"; return 1; }
    echo 0 > "$OUT/$cpu/check.rc"
    say "$cpu: replay in fp32 and int8, the graphs, the bad inputs"
    runs "$cpu" /src arm "$cpu" || return 1
    "$HOST_BIN/python" experiments/arm_compare.py compare "$OUT/x86" "$OUT/$cpu" \
        --precision "$expect" | tee "$OUT/$cpu/compare.md"
}

# the recordings both CPUs read (calibrate check needs 8 views for a verdict: 3 frames read
# "too few samples", exit 3) and the bad inputs made of them
make_inputs() {
    mkdir -p "$OUT/inputs"
    host edge-depth synth --mcap sim.mcap --frames 3 > /dev/null
    host edge-depth synth --mcap sim8.mcap --frames 8 > /dev/null
    host python "$REPO/experiments/arm_compare.py" prepare sim8.mcap .
}

main() {
    local first=${CPUS%% *} cpu failed="" rc=0
    need_host_tools
    need_binfmt
    need_root
    mkdir -p "$OUT/inputs"
    install_in_root "$first"
    if [ "$MODE" = fast ]; then
        say "$first: edge-depth demo --frames 2"
        arm "$first" edge-depth demo --frames 2 --out ../fast-demo > "$OUT/fast-demo.out" 2>&1 \
            || { tail -5 "$OUT/fast-demo.out"; say "FAIL: demo"; exit 1; }
        head -1 "$OUT/fast-demo.out"
        say "passed (fast: install and a two-frame demo as $first)"
        return
    fi
    say "x86-64: the recordings, the replays, the graphs, the bad inputs"
    make_inputs
    runs x86 "$REPO" host
    # calibrate check has no --runtime: this runs it on ONNX Runtime, as ARM does
    host python "$REPO/experiments/arm_compare.py" check sim8.mcap > "$OUT/x86/check.out" 2>&1 \
        || rc=$?
    echo "$rc" > "$OUT/x86/check.rc"
    for cpu in $CPUS; do
        on_model "$cpu" || failed+=" $cpu"
    done
    [ -z "$failed" ] || { say "FAILED on$failed"; exit 1; }
    say "passed on $CPUS"
}

main
