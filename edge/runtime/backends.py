"""The runtimes an exported graph runs on: ONNX Runtime (everywhere) and OpenVINO (x86).

Both read the same ONNX files, the int8 QDQ graphs included. A session here is anything with
`input_names`, `output_names` and `run(feeds) -> list of arrays`, so the engine does not care
which runtime it holds. `resolve_runtime("auto")` picks OpenVINO on x86-64 when it is
installed and ONNX Runtime elsewhere (ARM robots); the measurements behind that are in the
README's speed section (`tools/bench.py --runtimes`).

OpenVINO's CPU plugin would run float graphs in bf16 on a CPU with AVX512-BF16 or AMX by
default; that breaks index arithmetic (a column index of 319 rounds to 320 in bf16's 8-bit
mantissa, and GatherElements then fails or reads the wrong column), so every graph is
compiled with an explicit precision: f32 unless the caller asks for bf16 on a graph known
to tolerate it (`BF16_GRAPHS`: the encoder, whose outputs agree within the int8 budget).
"""

from __future__ import annotations

import hashlib
import os
import platform
import sys
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from edge_depth.errors import ConfigError

RUNTIMES = ("auto", "onnxruntime", "openvino")
BF16_GRAPHS = ("encoder",)  # parts whose bf16 run was measured to agree (README)


def openvino_available() -> bool:
    try:
        import openvino  # noqa: F401
    except ImportError:
        return False
    return True


# /proc/cpuinfo's names: x86 "flags" (VNNI, AMX), ARM "Features" (SDOT/UDOT: asimddp)
INT8_DOT_FLAGS = {"avx512_vnni", "avx_vnni", "amx_int8", "asimddp"}
# the instruction sets that decide the engine's speed, as benchmarks name them
ISA_FLAGS = (("avx2", "AVX2"), ("avx512f", "AVX-512"), ("avx512_vnni", "AVX512-VNNI"),
             ("avx_vnni", "AVX-VNNI"), ("avx512_bf16", "AVX512-BF16"), ("amx_tile", "AMX"),
             ("asimd", "NEON"), ("asimddp", "dotprod"))


# OpenVINO's oneDNN limited to these instruction sets (ONEDNN_MAX_CPU_ISA, as
# experiments/avx2_kernels.sh sets it) uses none of the CPU's AVX-512, VNNI, BF16 or AMX
LIMITED_ISAS = ("SSE41", "AVX", "AVX2")
ABOVE_AVX2 = ("avx512", "avx_vnni", "amx")  # /proc/cpuinfo flag prefixes


def kernel_flags(flags: set[str]) -> set[str]:
    """The CPU's flags the runtime's kernels may use: all of them, or, with ONEDNN_MAX_CPU_ISA
    at AVX2 or below, none above AVX2 (the int8 and bf16 choices then follow the kernels)."""
    if os.environ.get("ONEDNN_MAX_CPU_ISA", "").upper() not in LIMITED_ISAS:
        return flags
    return {f for f in flags if not f.startswith(ABOVE_AVX2)}


# ARM's /proc/cpuinfo has no "model name": its cores by "CPU part" (implementer 0x41, Arm),
# those of the boards robots use (Pi 4: A72; Pi 5: A76; RK3588: A76 + A55; Jetson Orin: A78AE)
ARM_CORES = {"0xd03": "Cortex-A53", "0xd05": "Cortex-A55", "0xd07": "Cortex-A57",
             "0xd08": "Cortex-A72", "0xd0b": "Cortex-A76", "0xd0c": "Neoverse-N1",
             "0xd41": "Cortex-A78", "0xd42": "Cortex-A78AE", "0xd4b": "Cortex-A78C"}
# the aarch64 aux vector's AT_HWCAP bits, by bit, under the names /proc/cpuinfo's "Features"
# prints them (Linux's arch/arm64/include/uapi/asm/hwcap.h)
AT_HWCAP = 16
ARM_HWCAP_NAMES = ("fp", "asimd", "evtstrm", "aes", "pmull", "sha1", "sha2", "crc32",
                   "atomics", "fphp", "asimdhp", "cpuid", "asimdrdm", "jscvt", "fcma", "lrcpc",
                   "dcpop", "sha3", "sm3", "sm4", "asimddp", "sha512", "sve", "asimdfhm")


def arm_hwcap_features(hwcap: int) -> set[str]:
    """The "Features" names of an aarch64 AT_HWCAP word (bits past ARM_HWCAP_NAMES dropped)."""
    return {name for bit, name in enumerate(ARM_HWCAP_NAMES) if hwcap >> bit & 1}


def _auxv_hwcap() -> int | None:
    """This process's AT_HWCAP word, as the kernel (or QEMU's user mode) gave it; None where
    libc has no getauxval."""
    import ctypes

    try:
        getauxval = ctypes.CDLL(None).getauxval
    except (OSError, AttributeError):
        return None
    getauxval.restype, getauxval.argtypes = ctypes.c_ulong, [ctypes.c_ulong]
    return int(getauxval(AT_HWCAP)) or None


def _read_cpuinfo() -> str:
    try:
        return Path("/proc/cpuinfo").read_text()
    except OSError:
        return ""


def _cpuinfo_entries(cpuinfo: str) -> dict[str, str]:
    """/proc/cpuinfo's first value of each key: the first processor's entries (on big.LITTLE
    the first core's), and the board's lines after the last processor (a Pi's "Model")."""
    entries: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        key, sep, value = line.partition(":")
        if sep and key.strip() not in entries:
            entries[key.strip()] = value.strip()
    return entries


def _cpu_model(entries: dict[str, str]) -> str:
    """x86's "model name"; on ARM the core named by its "CPU part", with the board's "Model"."""
    if "model name" in entries:
        return entries["model name"]
    core = ARM_CORES.get(entries.get("CPU part", "").lower()) if \
        entries.get("CPU implementer", "").lower() == "0x41" else None
    board = entries.get("Model")
    if core:
        return f"{core} ({board})" if board else core
    return board or platform.processor() or "unknown"


def cpu_description(cpuinfo: str | None = None) -> dict:
    """The CPU the graphs run on, for what benchmarks and quantization record: its model name,
    whether it has int8 dot-product instructions (AVX512-VNNI, AVX-VNNI, AMX, or ARM's
    SDOT/UDOT; None where unknown) and `isa`, which of ISA_FLAGS' instruction sets it has.
    Without dot products int8 graphs run no faster than float (ONNX Runtime ×1.00 on an AVX2
    host, docs/experiments.md), so ratios and quantization choices from the two kinds of CPU
    differ. `cpuinfo`: /proc/cpuinfo's text (read here on Linux, as the kernels see it:
    `kernel_flags`). On an aarch64 host whose /proc/cpuinfo has no "Features" (QEMU's user
    mode before 8.1 shows the host's x86 text), the features come from the aux vector's
    AT_HWCAP, which is what that line prints on a real board."""
    this_host = cpuinfo is None
    entries = _cpuinfo_entries(_read_cpuinfo() if cpuinfo is None else cpuinfo)
    text = entries.get("flags", entries.get("Features"))
    flags = None if text is None else set(text.split())
    model = _cpu_model(entries)
    if this_host and platform.machine().lower() in ("aarch64", "arm64") and \
            "Features" not in entries:
        hwcap = _auxv_hwcap()
        flags = None if hwcap is None else arm_hwcap_features(hwcap)
        model = platform.processor() or "unknown"
    if flags is not None and this_host:
        flags = kernel_flags(flags)
    return dict(model=model, int8_dot_product=None if flags is None
                else bool(flags & INT8_DOT_FLAGS),
                isa=[] if flags is None else [name for flag, name in ISA_FLAGS if flag in flags])


def cpu_has_bf16() -> bool:
    """Whether OpenVINO's CPU plugin reports native bf16 (AVX512-BF16 or AMX) and its kernels
    may use it (`kernel_flags`)."""
    if not openvino_available() or not kernel_flags({"avx512_bf16"}):
        return False
    import openvino as ov

    try:
        return "BF16" in ov.Core().get_property("CPU", "OPTIMIZATION_CAPABILITIES")
    except Exception:  # noqa: BLE001 - a plugin that cannot answer has no bf16 for us
        return False


def resolve_precision(precision: str, runtime: str, available, cpu: dict | None = None) -> str:
    """"auto" → "int8" where the bundle has it and it runs faster than float here: on a CPU
    with int8 dot products (`cpu_description`), or on OpenVINO, whose int8 kernels beat its
    float ones without them too (×1.12 on an AVX2-only EPYC); ONNX Runtime without them runs
    int8 no faster (×0.97 there), so "fp32" (docs/speed.md, "Precision by CPU"). `runtime`
    already resolved; `available`: the bundle's precisions."""
    if precision != "auto":
        return precision
    if "int8" not in available:
        return "fp32"
    dot = (cpu or cpu_description())["int8_dot_product"]
    return "int8" if dot or runtime == "openvino" else "fp32"


def resolve_int8_encoder(choice: str, precision: str, available: bool, bf16: bool,
                         runtime: str, cpu: dict | None = None) -> bool:
    """Whether the int8 precision runs the bundle's int8 encoder (model.json's "int8_encoder")
    instead of its float one: "on", "off", or "auto" = on OpenVINO where the float one would
    run in f32 on a CPU without int8 dot products (an AVX2-only x86: 16.9 → 12.2 ms with the
    accuracy held; docs/speed.md — judged on OpenVINO's kernels, which widen int8 products
    without saturating where there are no dot products). `bf16`: whether the float encoder
    would run in bf16; `runtime` already resolved."""
    if precision != "int8" or choice == "off":
        return False
    if not available:
        if choice == "on":
            raise ConfigError("int8_encoder", "a bundle with an int8 encoder (tools/quantize.py "
                              'writes one) for "on"', "on")
        return False
    if choice == "on":
        return True
    return runtime == "openvino" and not bf16 and \
        (cpu or cpu_description())["int8_dot_product"] is False


def resolve_runtime(runtime: str) -> str:
    """"auto" → "openvino" on x86-64 with OpenVINO installed, else "onnxruntime"; an explicit
    "openvino" without the package is a ConfigError naming the install."""
    if runtime not in RUNTIMES:
        raise ConfigError("engine.runtime", " | ".join(RUNTIMES), runtime)
    machine = platform.machine().lower()
    if runtime == "auto":
        x86 = machine in ("x86_64", "amd64")
        return "openvino" if x86 and openvino_available() else "onnxruntime"
    if runtime == "openvino" and not openvino_available():
        raise ConfigError("engine.runtime", "an installed OpenVINO (pip install openvino) or "
                          "runtime = \"onnxruntime\"", runtime)
    return runtime


class OrtSession:
    def __init__(self, path: Path, threads: int) -> None:
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        # three sessions take turns: a pool spinning after its call would steal the cores
        # from the next one (DESIGN.md)
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        self.path = Path(path)
        self._session = ort.InferenceSession(str(path), opts,
                                             providers=["CPUExecutionProvider"])
        self.input_names = [i.name for i in self._session.get_inputs()]
        self.output_names = [o.name for o in self._session.get_outputs()]

    def run(self, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        return self._session.run(None, feeds)


# OpenVINO graphs compiled in this process, the latest COMPILED_KEPT, by the file's content,
# the outputs kept, the input shapes and the config: a process that opens a bundle again (a
# second engine, quantization's candidates, a test suite) compiles each graph once, ~0.1-0.5 s
# each. A compiled graph serves any number of sessions: each has its own infer request.
COMPILED_KEPT = 16
_COMPILED: OrderedDict[tuple, Any] = OrderedDict()
_COMPILED_LOCK = threading.Lock()


class OpenVinoSession:
    """`outputs`: the output names the caller reads (None: all); the others are cut from the
    graph before compiling, and what only they needed is not computed or copied out. A graph
    that takes any size is compiled for the shapes of the first feeds, and again when they
    change (a new camera size: once, not per frame), so every run is a static-shape one."""

    def __init__(self, path: Path, threads: int, bf16: bool = False,
                 outputs: set[str] | None = None) -> None:
        import openvino as ov

        self._config = {"INFERENCE_NUM_THREADS": int(threads), "PERFORMANCE_HINT": "LATENCY",
                        "INFERENCE_PRECISION_HINT": "bf16" if bf16 else "f32"}
        self._core = ov.Core()
        self.path = Path(path)
        self._model = self._core.read_model(str(path))
        # the file's content, not its name or time: quantization rewrites a file within the
        # timestamps' resolution
        self._digest = hashlib.blake2b(self.path.read_bytes(), digest_size=16).hexdigest()
        if outputs is not None:
            for result in list(self._model.get_results()):
                if not result.output(0).get_names() & outputs:
                    self._model.remove_result(result)
        self.input_names = [i.get_any_name() for i in self._model.inputs]
        self.output_names = [o.get_any_name() for o in self._model.outputs]
        self.bf16 = bf16
        self._shapes: dict[str, tuple[int, ...]] = {}  # what an any-size graph is compiled for
        self._request: Any = None
        self._outputs: list[Any] = []
        self._any_size = self._model.is_dynamic()
        if not self._any_size:
            self._compile()

    def _compile(self) -> None:
        try:
            compiled = self._compiled()
        except RuntimeError as exc:
            if not self.bf16:
                raise
            # a CPU that reports bf16 and cannot compile it (kernels limited by
            # ONEDNN_MAX_CPU_ISA, a hypervisor that hides the instructions): f32, said once
            first = str(exc).strip().splitlines()[-1][:120] if str(exc).strip() else ""
            print(f"edge-depth: OpenVINO could not compile {self.path.name} in bf16 ({first}); "
                  "running it in f32", file=sys.stderr)
            self.bf16 = False
            self._config["INFERENCE_PRECISION_HINT"] = "f32"
            compiled = self._compiled()
        self._request = compiled.create_infer_request()
        self._outputs = list(compiled.outputs)

    def _compiled(self) -> Any:
        """The graph compiled for the current shapes and config, or the same one compiled
        before in this process (`COMPILED_KEPT`)."""
        key = (self._digest, tuple(self.output_names),
               tuple(str(i.get_partial_shape()) for i in self._model.inputs),
               tuple(sorted(self._config.items())))
        with _COMPILED_LOCK:
            compiled = _COMPILED.get(key)
            if compiled is not None:
                _COMPILED.move_to_end(key)
                return compiled
        compiled = self._core.compile_model(self._model, "CPU", self._config)
        with _COMPILED_LOCK:
            _COMPILED[key] = compiled
            while len(_COMPILED) > COMPILED_KEPT:
                _COMPILED.popitem(last=False)
        return compiled

    def run(self, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        if self._any_size:  # a static graph (each run of a step) skips the comparison
            shapes = {k: tuple(feeds[k].shape) for k in self.input_names}
            if shapes != self._shapes:
                self._model.reshape({k: list(v) for k, v in shapes.items()})
                self._compile()
                self._shapes = shapes
        # inputs without a copy (the call is synchronous; the correlation volume is ~2.6 MB
        # at 640x400, fed to every step), outputs copied: a step's outputs are the next
        # step's inputs
        results = self._request.infer({k: feeds[k] for k in self.input_names},
                                      share_inputs=True, share_outputs=False)
        return [results[o] for o in self._outputs]


def open_session(path: Path, runtime: str, threads: int, bf16: bool = False,
                 outputs: set[str] | None = None):
    """`runtime` already resolved; `bf16` and `outputs` (the outputs read: the others cut
    from the graph) are honoured by OpenVINO only."""
    if runtime == "openvino":
        return OpenVinoSession(path, threads, bf16, outputs)
    return OrtSession(path, threads)
