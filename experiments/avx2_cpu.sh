#!/usr/bin/env bash
# A command run on an emulated AVX2-only CPU (QEMU user mode, CPU model Haswell: AVX2 and FMA,
# no AVX-512, no VNNI, no BF16): every library picks its kernels from the CPU it is shown, ONNX
# Runtime's included, which experiments/avx2_kernels.sh cannot limit. For what ONNX Runtime
# computes on an AVX2-only host, never for how fast (emulated vector code runs ~1000x slower:
# a 512x512 float matrix product 8 s against 1 ms), and not for OpenVINO: QEMU 7.2's AVX2
# emulation runs OpenVINO's JIT kernels wrong (docs/experiments.md, 2026-12-07 01:10). A
# process the command starts runs natively again, so run pytest in one process
# (`-p no:xdist`). Needs `apt-get install qemu-user`.
#     bash experiments/avx2_cpu.sh .venv/bin/python experiments/ort_on_avx2.py out/avx2.npz
set -euo pipefail
if ! command -v qemu-x86_64 > /dev/null; then
    echo "avx2_cpu.sh: qemu-x86_64 not found (apt-get install qemu-user)" >&2
    exit 2
fi
# the project reads /proc/cpuinfo, which QEMU passes through from the host: this variable makes
# it drop the flags above AVX2 there too (edge.runtime.backends.kernel_flags)
export ONEDNN_MAX_CPU_ISA=AVX2
# Haswell without the system features QEMU's TCG lacks (it warns about each, on every thread)
exec qemu-x86_64 -cpu Haswell-v4,-pcid,-x2apic,-tsc-deadline,-invpcid,-spec-ctrl "$@"
