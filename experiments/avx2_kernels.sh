#!/usr/bin/env bash
# A command run with an AVX2-only CPU's kernels on a host that has AVX-512 (and VNNI, BF16):
# OpenVINO's oneDNN limited to AVX2 (its int8 then without dot products, no bf16), OpenCV's
# AVX-512 dispatch off, NumPy's AVX-512 loops off, OpenBLAS and numba as Haswell. The host's clock,
# caches and memory stay its own: ratios between stages and against SGBM carry over to an
# AVX2 CPU, milliseconds do not. ONNX Runtime's kernels cannot be limited (use OpenVINO).
#     bash experiments/avx2_kernels.sh .venv/bin/python tools/bench.py --runs 3
set -euo pipefail
export ONEDNN_MAX_CPU_ISA=AVX2
export OPENCV_CPU_DISABLE=AVX512-SKX
export NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR"
export OPENBLAS_CORETYPE=Haswell
# numba compiles for Haswell (AVX2, no AVX-512): the name alone is not enough, numba then keeps
# the host's features (AVX-512 included); with a feature list LLVM takes Haswell's own
export NUMBA_CPU_NAME=haswell
export NUMBA_CPU_FEATURES="+64bit,+aes,+avx,+avx2,+bmi,+bmi2,+cmov,+cx16,+f16c,+fma,+fsgsbase,+fxsr,+lzcnt,+mmx,+movbe,+pclmul,+popcnt,+rdrnd,+sahf,+sse,+sse2,+sse3,+sse4.1,+sse4.2,+ssse3,+xsave,+xsaveopt"
exec "$@"
