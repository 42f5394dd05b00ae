"""The engine's runtimes: how `auto` chooses, and OpenVINO agreeing with ONNX Runtime."""

from __future__ import annotations

import numpy as np
import pytest

from edge_depth.config import load_robot_config
from edge_depth.errors import ConfigError
from edge_depth.metrics import disparity_metrics
from edge_depth.runtime import backends
from edge_depth.runtime.engine import Engine
from edge_depth.sim import RigConfig, make_sample


@pytest.mark.parametrize("machine, installed, expected", [
    ("x86_64", True, "openvino"), ("AMD64", True, "openvino"), ("x86_64", False, "onnxruntime"),
    ("aarch64", True, "onnxruntime"), ("armv7l", False, "onnxruntime")])
def test_auto_takes_openvino_on_x86_when_installed_and_onnxruntime_elsewhere(
        monkeypatch, machine, installed, expected):
    monkeypatch.setattr(backends.platform, "machine", lambda: machine)
    monkeypatch.setattr(backends, "openvino_available", lambda: installed)
    assert backends.resolve_runtime("auto") == expected
    assert backends.resolve_runtime("onnxruntime") == "onnxruntime"


def test_the_cpu_description_says_whether_int8_has_dot_product_instructions(monkeypatch):
    from edge_depth.tools.bench_report import host_line, machine_line

    entry = "processor\t: {n}\nmodel name\t: {model}\nflags\t\t: fpu sse2 avx2 {extra}\n\n"
    epyc = entry.format(n=0, model="AMD EPYC 7B13", extra="fma") * 2
    xeon = entry.format(n=0, model="Intel Xeon", extra="avx512f avx512_vnni amx_bf16")
    assert backends.cpu_description(epyc) == dict(model="AMD EPYC 7B13", int8_dot_product=False,
                                                  isa=["AVX2"])
    assert backends.cpu_description(xeon) == dict(
        model="Intel Xeon", int8_dot_product=True, isa=["AVX2", "AVX-512", "AVX512-VNNI"])
    assert backends.cpu_description(entry.format(n=0, model="x", extra="avx_vnni"))[
        "int8_dot_product"] is True
    # ARM robots (a Raspberry Pi 5's Cortex-A76, a Jetson's A78AE): "Features", no model name
    arm = "processor\t: 0\nBogoMIPS\t: 108.00\nFeatures\t: fp asimd {}\n"
    monkeypatch.setattr(backends.platform, "processor", lambda: "")
    assert backends.cpu_description(arm.format("asimddp")) == dict(
        model="unknown", int8_dot_product=True, isa=["NEON", "dotprod"])
    assert backends.cpu_description(arm.format("crc32"))["int8_dot_product"] is False
    # no /proc/cpuinfo (macOS, Windows): the platform's name, the instructions unknown
    monkeypatch.setattr(backends.platform, "processor", lambda: "arm")
    assert backends.cpu_description("") == dict(model="arm", int8_dot_product=None, isa=[])
    machine = dict(others_cpu_share=0.0, load_avg_1min=0.1, sgbm_p90_over_p10=1.2, busy=False)
    assert "int8 dot product" not in machine_line(machine)  # benches saved before the field
    assert "UNSTEADY" not in machine_line(machine)
    # SGBM bimodal (a spinning thread took a core from it half the time): flagged
    assert "SGBM UNSTEADY" in machine_line(dict(machine, sgbm_p90_over_p10=1.6))
    line = machine_line(dict(machine, cpu=backends.cpu_description(epyc)))
    assert line.endswith("; CPU AMD EPYC 7B13 (AVX2), int8 dot product (VNNI/AMX): no")
    assert host_line(backends.cpu_description(xeon)).startswith(
        "host: Intel Xeon; ISA AVX2, AVX-512, AVX512-VNNI; int8 dot product: yes")
    from edge_depth.tools.bench_report import KERNEL_LIMITS

    for var, _ in KERNEL_LIMITS:  # this run's own limits (the suite may run under them)
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX2")  # an AVX2 CPU's kernels, emulated
    monkeypatch.setenv("OPENCV_CPU_DISABLE", "AVX512-SKX")
    assert host_line(backends.cpu_description(xeon)).endswith(
        "; kernels limited: OpenVINO/oneDNN up to AVX2, OpenCV without AVX512-SKX")


# /proc/cpuinfo of a Raspberry Pi 5 (Cortex-A76: SDOT/UDOT, "asimddp") and of a Pi 4
# (Cortex-A72: NEON without dot products), the first core and the board's lines
PI5_CPUINFO = """processor\t: 0
BogoMIPS\t: 108.00
Features\t: fp asimd evtstrm aes pmull sha1 sha2 crc32 atomics fphp asimdhp cpuid asimdrdm \
lrcpc dcpop asimddp
CPU implementer\t: 0x41
CPU architecture: 8
CPU variant\t: 0x4
CPU part\t: 0xd0b
CPU revision\t: 1

Revision\t: c04170
Serial\t\t: 3f4e9c1a2b7d6e50
Model\t\t: Raspberry Pi 5 Model B Rev 1.0
"""
PI4_CPUINFO = """processor\t: 0
BogoMIPS\t: 108.00
Features\t: fp asimd evtstrm crc32 cpuid
CPU implementer\t: 0x41
CPU architecture: 8
CPU variant\t: 0x0
CPU part\t: 0xd08
CPU revision\t: 3

Hardware\t: BCM2835
Revision\t: c03111
Serial\t\t: 10000000a1b2c3d4
Model\t\t: Raspberry Pi 4 Model B Rev 1.1
"""
# the AT_HWCAP words QEMU's user mode gives its cortex-a76 and cortex-a72 models
# (`getauxval(AT_HWCAP)` under qemu-aarch64-static 7.2, QEMU_CPU=cortex-a76 / cortex-a72)
A76_HWCAP, A72_HWCAP = 0x119FFB, 0x8FB


@pytest.mark.parametrize("cpuinfo, model, dot, isa, precision", [
    (PI5_CPUINFO, "Cortex-A76 (Raspberry Pi 5 Model B Rev 1.0)", True, ["NEON", "dotprod"],
     "int8"),
    (PI4_CPUINFO, "Cortex-A72 (Raspberry Pi 4 Model B Rev 1.1)", False, ["NEON"], "fp32")])
def test_an_arm_board_runs_int8_on_onnxruntime_only_with_dot_products(
        monkeypatch, cpuinfo, model, dot, isa, precision):
    cpu = backends.cpu_description(cpuinfo)
    assert cpu == dict(model=model, int8_dot_product=dot, isa=isa)
    monkeypatch.setattr(backends.platform, "machine", lambda: "aarch64")
    monkeypatch.setattr(backends, "openvino_available", lambda: True)  # an x86 choice only
    runtime = backends.resolve_runtime("auto")
    assert runtime == "onnxruntime"
    both = {"fp32": {}, "int8": {}}
    assert backends.resolve_precision("auto", runtime, both, cpu) == precision


def test_the_aux_vector_names_the_features_as_cpuinfo_prints_them():
    a76 = backends.arm_hwcap_features(A76_HWCAP)
    a72 = backends.arm_hwcap_features(A72_HWCAP)
    assert a72 == {"fp", "asimd", "aes", "pmull", "sha1", "sha2", "crc32", "cpuid"}
    assert a76 == a72 | {"atomics", "fphp", "asimdhp", "asimdrdm", "lrcpc", "dcpop", "asimddp"}
    # a Pi 5's line: QEMU's A76 and the kernel's timer event stream, which QEMU does not set
    features = next(line for line in PI5_CPUINFO.splitlines() if line.startswith("Features"))
    assert set(features.split(":")[1].split()) == a76 | {"evtstrm"}
    assert backends.arm_hwcap_features(0) == set()
    assert backends.arm_hwcap_features(1 << 40) == set()  # a bit this table does not name


@pytest.mark.parametrize("hwcap, dot, isa", [
    (A76_HWCAP, True, ["NEON", "dotprod"]), (A72_HWCAP, False, ["NEON"]), (None, None, [])])
def test_an_aarch64_host_showing_another_cpus_cpuinfo_reads_its_aux_vector(
        monkeypatch, hwcap, dot, isa):
    """QEMU's user mode before 8.1 passes the x86 host's /proc/cpuinfo through: its "flags"
    say nothing of the emulated ARM CPU, whose features the aux vector carries."""
    x86 = "processor\t: 0\nmodel name\t: AMD EPYC\nflags\t\t: avx2 avx512f avx512_vnni\n"
    monkeypatch.setattr(backends, "_read_cpuinfo", lambda: x86)
    monkeypatch.setattr(backends, "_auxv_hwcap", lambda: hwcap)
    monkeypatch.setattr(backends.platform, "processor", lambda: "")
    monkeypatch.setattr(backends.platform, "machine", lambda: "aarch64")
    assert backends.cpu_description() == dict(model="unknown", int8_dot_product=dot, isa=isa)
    # a board's own text is read as it is (the aux vector only stands in for a missing one)
    monkeypatch.setattr(backends, "_read_cpuinfo", lambda: PI4_CPUINFO)
    monkeypatch.setattr(backends, "_auxv_hwcap", lambda: A76_HWCAP)
    assert backends.cpu_description()["int8_dot_product"] is False
    monkeypatch.setattr(backends.platform, "machine", lambda: "x86_64")  # x86: as it reads
    monkeypatch.delenv("ONEDNN_MAX_CPU_ISA", raising=False)  # the suite may run under it
    monkeypatch.setattr(backends, "_read_cpuinfo", lambda: x86)
    assert backends.cpu_description()["int8_dot_product"] is True


def test_an_unknown_or_missing_runtime_is_one_clear_error(monkeypatch):
    with pytest.raises(ConfigError, match="tensorrt"):
        backends.resolve_runtime("tensorrt")
    monkeypatch.setattr(backends, "openvino_available", lambda: False)
    with pytest.raises(ConfigError, match="pip install openvino"):
        backends.resolve_runtime("openvino")


def test_the_robot_config_takes_runtime_and_bf16(tmp_path):
    path = tmp_path / "robot.toml"
    path.write_text('[camera]\nsource = "sim"\n[lidar]\nmodel = "sim"\n'
                    '[engine]\nruntime = "onnxruntime"\nbf16 = "off"\n')
    engine = load_robot_config(path).engine
    assert (engine.runtime, engine.bf16_choice) == ("onnxruntime", False)
    path.write_text('[camera]\nsource = "sim"\n[lidar]\nmodel = "sim"\n'
                    '[engine]\nruntime = "tensorrt"\n')
    with pytest.raises(ConfigError, match="runtime"):
        load_robot_config(path)


def _scene(seed: int = 1_000_002):
    sample = make_sample(seed, RigConfig(width=640, height=400), "beams16")
    sparse, valid = sample.sparse_disparity("left")
    return sample, (sparse * valid).astype(np.float32)


def test_onnxruntime_engine_describes_itself_and_never_uses_bf16():
    engine = Engine(precision="int8", threads=1, runtime="onnxruntime", bf16=True)
    assert engine.runtime == "onnxruntime" and not engine.bf16
    assert engine.describe() == ("int8 on onnxruntime, band refinement, weighted median 9x9/2 "
                                 "(the bundle's)")


@pytest.mark.skipif(not backends.openvino_available(), reason="OpenVINO not installed")
def test_openvino_runs_the_same_bundle_as_onnxruntime():
    """fp32 agrees to numerical noise; the int8 step (QDQ read by OpenVINO) within the int8
    budget; the bf16 encoder keeps the accuracy against ground truth."""
    sample, sparse = _scene()
    args = (sample.left, sample.right, sparse)
    # the graphs' outputs (the refinement after them off)
    ort32 = Engine(precision="fp32", threads=2, runtime="onnxruntime",
                   refine="off", edge_median="off").infer(*args).disparity
    ov32 = Engine(precision="fp32", threads=2, runtime="openvino", bf16=False, edge_median="off",
                  refine="off")
    assert ov32.describe() == "fp32 on openvino, no refinement"
    assert float(np.abs(ov32.infer(*args).disparity - ort32).max()) < 0.05
    ort8 = Engine(precision="int8", threads=2, runtime="onnxruntime",
                  refine="off", edge_median="off").infer(*args).disparity
    ov8 = Engine(precision="int8", threads=2, runtime="openvino", bf16=False,
                 refine="off", edge_median="off").infer(*args)
    assert float(np.abs(ov8.disparity - ort8).mean()) < 0.1
    gt = sample.disp_left
    base = disparity_metrics(ort8, gt)["epe"]
    bf16 = Engine(precision="int8", threads=2, runtime="openvino", bf16=True, edge_median="off",
                  refine="off")
    assert bf16.bf16 and bf16.describe() == "int8 on openvino (bf16 encoder), no refinement"
    epe = disparity_metrics(bf16.infer(*args).disparity, gt)["epe"]
    assert epe < 1.05 * base + 0.02


@pytest.mark.skipif(not backends.openvino_available(), reason="OpenVINO not installed")
def test_openvino_computes_only_the_encoder_outputs_the_other_graphs_read():
    """OpenVINO's encoder is compiled with only the outputs the step and the upsampling read
    (a bundle exported for an older head wrote 1/4 features the shipped one does not read);
    a session asked for a subset has it."""
    from edge_depth.runtime.engine import DEFAULT_BUNDLE

    ov = Engine(precision="fp32", threads=1, runtime="openvino", bf16=False, edge_median="off",
                refine="off")
    ort = Engine(precision="fp32", threads=1, runtime="onnxruntime", refine="off",
                 edge_median="off")
    read = {"disparity", "hidden"}.union(ov.sessions["step"].input_names,
                                         ov.sessions["upsample"].input_names)
    assert set(ov.graphs.enc_outputs) == set(ort.graphs.enc_outputs) & read == set(
        ort.graphs.enc_outputs)
    session = backends.OpenVinoSession(DEFAULT_BUNDLE / "encoder.onnx", 1,
                                       outputs={"corr", "hidden"})
    assert sorted(session.output_names) == ["corr", "hidden"]


@pytest.mark.parametrize("dot, runtime, expected", [
    (True, "onnxruntime", "int8"), (True, "openvino", "int8"),
    (False, "openvino", "int8"),        # OpenVINO's int8 kernels win without dot products too
    (False, "onnxruntime", "fp32"),     # ONNX Runtime's do not
    (None, "onnxruntime", "fp32")])     # instructions unknown: float
def test_auto_precision_is_int8_where_the_cpu_runs_it_faster(dot, runtime, expected):
    cpu = dict(model="x", int8_dot_product=dot, isa=[])
    both = {"fp32": {}, "int8": {}}
    assert backends.resolve_precision("auto", runtime, both, cpu) == expected
    assert backends.resolve_precision("auto", runtime, {"fp32": {}}, cpu) == "fp32"
    assert backends.resolve_precision("int8", runtime, both, cpu) == "int8"   # as asked
    assert backends.resolve_precision("fp32", runtime, both, cpu) == "fp32"


def test_the_engine_resolves_auto_precision_once_and_says_which(monkeypatch):
    monkeypatch.setattr(backends, "cpu_description",
                        lambda: dict(model="x", int8_dot_product=False, isa=["AVX2"]))
    engine = Engine(runtime="onnxruntime", threads=1)
    assert engine.options.precision == "auto" and engine.precision == "fp32"
    assert engine.describe().startswith("fp32 on onnxruntime")


def test_a_cpu_that_cannot_compile_bf16_runs_the_graph_in_f32_and_says_so(capsys, monkeypatch):
    """A CPU that reports bf16 and cannot compile it (OpenVINO's kernels limited to AVX2, a
    hypervisor hiding the instructions) costs a line, not the daemon."""
    pytest.importorskip("openvino")
    from collections import OrderedDict

    from edge_depth.runtime.engine import DEFAULT_BUNDLE

    monkeypatch.setattr(backends, "_COMPILED", OrderedDict())  # nothing compiled before

    session = backends.OpenVinoSession(DEFAULT_BUNDLE / "upsample.onnx", 1, bf16=True)
    compile_model = session._core.compile_model
    asked = []

    class RefusesBf16:
        def compile_model(self, model, device, config):
            asked.append(config["INFERENCE_PRECISION_HINT"])
            if config["INFERENCE_PRECISION_HINT"] == "bf16":
                raise RuntimeError("Exception from src/inference\nobject is not initialized")
            return compile_model(model, device, config)

    session._core = RefusesBf16()
    feeds = {i.get_any_name(): np.zeros([d.get_length() if d.is_static else 8
                                         for d in i.get_partial_shape()], np.float32)
             for i in session._model.inputs}
    outputs = session.run(feeds)
    assert asked == ["bf16", "f32"] and not session.bf16 and outputs
    assert "could not compile upsample.onnx in bf16 (object is not initialized)" in \
        capsys.readouterr().err
    # an engine whose encoder fell back so no longer says "bf16 encoder" (its first line, the
    # bench's header and JSON)
    from types import SimpleNamespace

    from edge_depth.runtime.engine import Engine

    engine = SimpleNamespace(bf16=True, sessions={"encoder": session})
    assert Engine.bf16_encoder.fget(engine) is False  # type: ignore[attr-defined]
    session.bf16 = True
    assert Engine.bf16_encoder.fget(engine) is True  # type: ignore[attr-defined]


@pytest.mark.parametrize("choice, precision, bf16, runtime, dot, expected", [
    ("auto", "int8", False, "openvino", False, True),  # AVX2-only x86: the f32 encoder's place
    ("auto", "int8", True, "openvino", False, False),  # bf16 runs the float one faster, closer
    ("auto", "int8", False, "openvino", True, False),  # VNNI: judged on the pairs, not taken
    ("auto", "int8", False, "openvino", None, False),  # instructions unknown
    ("auto", "int8", False, "onnxruntime", False, False),  # judged on OpenVINO's kernels only
    ("auto", "fp32", False, "openvino", False, False),  # only the int8 precision has it
    ("on", "int8", True, "onnxruntime", True, True),
    ("off", "int8", False, "openvino", False, False)])
def test_the_int8_encoder_runs_where_the_float_one_would_run_in_f32_without_dot_products(
        choice, precision, bf16, runtime, dot, expected):
    cpu = dict(model="x", int8_dot_product=dot, isa=[])
    assert backends.resolve_int8_encoder(choice, precision, True, bf16, runtime,
                                         cpu) is expected
    assert backends.resolve_int8_encoder(choice if choice != "on" else "auto", precision,
                                         False, bf16, runtime, cpu) is False  # none in the bundle
    with pytest.raises(ConfigError, match="int8_encoder"):
        backends.resolve_int8_encoder("on", "int8", False, False, runtime, cpu)


def test_kernels_limited_to_avx2_hide_the_instructions_above_it(monkeypatch):
    """experiments/avx2_kernels.sh's ONEDNN_MAX_CPU_ISA: the choices follow the kernels the
    runtime may use, not the flags the CPU reports."""
    flags = {"avx2", "avx512f", "avx512_vnni", "avx512_bf16", "avx_vnni", "amx_int8", "fma"}
    monkeypatch.delenv("ONEDNN_MAX_CPU_ISA", raising=False)
    assert backends.kernel_flags(flags) == flags
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX2")
    assert backends.kernel_flags(flags) == {"avx2", "fma"}
    assert backends.cpu_has_bf16() is False
    text = "model name\t: x\nflags\t\t: " + " ".join(sorted(flags)) + "\n"
    assert backends.cpu_description(text)["int8_dot_product"] is True  # a given text: as is
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX512_CORE_AMX")
    assert backends.kernel_flags(flags) == flags


def test_the_engine_opens_the_bundles_int8_encoder_and_says_so(monkeypatch):
    """`auto` on OpenVINO on an AVX2-only CPU (no bf16, no dot products) runs the int8 encoder
    and says so; the same bundle with it off runs the float one, within int8's rounding."""
    pytest.importorskip("openvino")
    from edge_depth.runtime import engine as engine_module
    from edge_depth.runtime.engine import DEFAULT_BUNDLE

    monkeypatch.setattr(backends, "cpu_description",
                        lambda: dict(model="x", int8_dot_product=False, isa=["AVX2"]))
    monkeypatch.setattr(engine_module, "cpu_has_bf16", lambda: False)
    engine = Engine(runtime="openvino", threads=1, refine="off", edge_median="off")
    assert engine.precision == "int8" and engine.int8_encoder and not engine.bf16
    assert engine.sessions["encoder"].path == DEFAULT_BUNDLE / "encoder.int8.onnx"
    assert engine.describe().startswith("int8 on openvino (int8 encoder)")
    floating = Engine(runtime="openvino", threads=1, refine="off", edge_median="off",
                      int8_encoder="off")
    assert floating.sessions["encoder"].path == DEFAULT_BUNDLE / "encoder.onnx"
    assert "encoder)" not in floating.describe()
    sample = make_sample(3, RigConfig(), "beams16")
    sparse, valid = sample.sparse_disparity("left")
    a, b = (e.infer(sample.left, sample.right, (sparse * valid).astype(np.float32), iters=2)
            for e in (engine, floating))
    # the same network within int8's rounding (0.07 px on the calibration frames)
    assert 0.0 < float(np.abs(a.disparity - b.disparity).mean()) < 0.3
    # ONNX Runtime only as asked: its int8 encoder was not judged by `auto`'s rule
    assert not Engine(runtime="onnxruntime", precision="int8", threads=1,
                      refine="off", edge_median="off").int8_encoder
    assert Engine(runtime="onnxruntime", precision="int8", threads=1, refine="off",
                  edge_median="off", int8_encoder="on").int8_encoder


def test_openvino_compiles_a_graph_once_per_process_and_a_changed_file_again(tmp_path,
                                                                             monkeypatch):
    """A second session of the same file, outputs, shapes and config takes the graph compiled
    for the first (with its own infer request); other shapes, or a file rewritten with other
    content, are compiled anew; only the latest COMPILED_KEPT stay."""
    ov = pytest.importorskip("openvino")
    import shutil
    from collections import OrderedDict

    import onnx

    from edge_depth.runtime.engine import DEFAULT_BUNDLE

    monkeypatch.setattr(backends, "_COMPILED", OrderedDict())
    monkeypatch.setattr(backends, "COMPILED_KEPT", 2)
    compiles = []
    compile_model = ov.Core.compile_model

    def counted(core, *args, **kwargs):
        compiles.append(1)
        return compile_model(core, *args, **kwargs)

    monkeypatch.setattr(ov.Core, "compile_model", counted)
    graph = tmp_path / "upsample.onnx"
    shutil.copy(DEFAULT_BUNDLE / "upsample.onnx", graph)

    def run(size: int) -> list[np.ndarray]:
        session = backends.OpenVinoSession(graph, 1)
        rng = np.random.default_rng(3)
        feeds = {i.get_any_name(): rng.standard_normal(
            [d.get_length() if d.is_static else size for d in i.get_partial_shape()]
        ).astype(np.float32) for i in session._model.inputs}
        return session.run(feeds)

    first, again = run(8), run(8)
    assert len(compiles) == 1  # the second session compiled nothing
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a, b)
    run(16)  # other shapes
    assert len(compiles) == 2 and len(backends._COMPILED) == 2
    model = onnx.load(str(graph))
    model.doc_string = "rewritten"  # other content at the same path
    onnx.save(model, str(graph))
    run(8)
    assert len(compiles) == 3 and len(backends._COMPILED) == 2  # the oldest dropped
