"""A bundle's graphs as one runtime's sessions: model.json read and checked, the encoder, step
and upsampling opened at the resolved precision (the int8 encoder or bf16 where chosen), and
which of the encoder's outputs each later graph reads, by name (`edge.runtime.engine` runs
them)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from edge_depth.errors import ConfigError
from edge_depth.runtime.backends import BF16_GRAPHS, open_session


def load_bundle_meta(bundle: Path) -> dict:
    path = Path(bundle) / "model.json"
    if not path.is_file():
        raise ConfigError("bundle", "a directory with model.json (tools/export.py)", str(bundle))
    try:
        meta = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError("bundle", f"valid JSON in {path}", str(exc)) from None
    missing = [k for k in ("size", "downsample", "precisions") if not isinstance(meta, dict)
               or k not in meta]
    if missing:
        raise ConfigError("bundle", f"{path} with the keys size, downsample and precisions "
                          "(tools/export.py writes them)", f"missing {missing}")
    return meta


class BundleGraphs:
    """`sessions` ("encoder", "step", "upsample"), the names that wire them (`enc_outputs`,
    `step_state`: what the step reads of the encoder's besides the disparity and hidden
    state; `upsample_inputs`: the frame's buffers the upsampling reads; `upsample_state`: the
    encoder's outputs it reads) and `has_confidence`. ConfigError naming the graph that does
    not load or the graphs that were not exported together."""

    def __init__(self, bundle: Path, meta: dict, precision: str, runtime: str, threads: int,
                 bf16: bool, int8_encoder: bool) -> None:
        self.bundle, self.meta, self.precision = bundle, meta, precision
        self.runtime, self.threads, self.bf16 = runtime, threads, bf16
        files = meta["precisions"].get(precision)
        if files is None:
            raise ConfigError("precision", f"one of {sorted(meta['precisions'])}", precision)
        if int8_encoder:
            files = dict(files, encoder=meta["int8_encoder"]["file"])
        self.sessions = self._open(files)
        self._wire()
        self._reference_upsample: Any = None

    def _open(self, files: dict[str, str]) -> dict[str, Any]:
        """The graphs as sessions, the encoder last: it computes only what the step and the
        upsampling read (OpenVINO; version 10's upsampling reads no 1/4 features: 1.4 ms of a
        frame at one thread)."""
        sessions: dict[str, Any] = {}
        for part in sorted(files, key=lambda p: p == "encoder"):
            name = files[part]
            read = None if part != "encoder" else {"disparity", "hidden"}.union(
                *(sessions[p].input_names for p in sessions))
            try:
                sessions[part] = open_session(self.bundle / name, self.runtime, self.threads,
                                              self.bf16 and part in BF16_GRAPHS, read)
            except Exception as exc:  # noqa: BLE001 - the runtimes' errors have no base
                first = str(exc).strip().splitlines()[0][:160] if str(exc).strip() else ""
                raise ConfigError("bundle", f"a loadable ONNX graph at {self.bundle / name} "
                                  "(re-export with tools/export.py)",
                                  f"{type(exc).__name__}: {first}") from None
        return sessions

    def _wire(self) -> None:
        """Graphs from two exports (newer bundles pass the context as two precomputed terms,
        older ones as itself; a refinement's version decides what the upsampling reads) are a
        ConfigError here rather than a failure on frame 1."""
        self.enc_outputs = self.sessions["encoder"].output_names
        self.step_state = [n for n in self.sessions["step"].input_names
                           if n not in ("disparity", "hidden")]
        upsample = self.sessions["upsample"]
        fed = {"disparity", "hidden", *self.enc_outputs}
        for part, extra in (("step", set()), ("upsample", {"left", "right", "sparse", "valid"})):
            missing = [n for n in self.sessions[part].input_names if n not in fed | extra]
            if missing:
                raise ConfigError("bundle", f"graphs exported together (tools/export.py): "
                                  f"{part}.onnx reads what encoder.onnx writes",
                                  f"{part}.onnx needs {', '.join(missing)}, which "
                                  f"{self.bundle / 'encoder.onnx'} does not output")
        # a refining upsample graph also takes the images (and, versions 2-3, the LiDAR;
        # version 4: the encoder's 1/4 features and the LiDAR)
        self.upsample_inputs = [n for n in upsample.input_names
                                if n in ("left", "right", "sparse", "valid")]
        self.upsample_state = [n for n in upsample.input_names if n in self.enc_outputs
                               and n not in ("disparity", "hidden")]
        self.has_confidence = len(upsample.output_names) > 1

    def disparity_upsample(self) -> Any:
        """The upsampling without the confidence (OpenVINO cuts it from the graph: 3.2
        instead of 5.8 ms at 640x400), opened on first use; elsewhere the frame's own."""
        if self.runtime != "openvino" or len(self.sessions["upsample"].output_names) < 2:
            return self.sessions["upsample"]
        if self._reference_upsample is None:
            name = self.meta["precisions"][self.precision]["upsample"]
            first = self.sessions["upsample"].output_names[0]
            self._reference_upsample = open_session(
                self.bundle / name, self.runtime, self.threads,
                self.bf16 and "upsample" in BF16_GRAPHS, {first})
        return self._reference_upsample
