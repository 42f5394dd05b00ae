"""Every engine setting in one place: `EngineOptions`, its defaults and a line of doc each.

The robot file's `[engine]` table (`edge.config`), the engine flags of `replay` and `fleet`
(`add_engine_arguments`) and the configuration reference (`reference_table`, in
docs/configuration.md) are derived from these fields, never written beside them. A bundle's
own settings (model.json's "engine", `bundle_preset`) are a preset: the fields left at
"bundle" take them, once, when the engine loads (`EngineOptions.resolved`).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field, fields, replace
from typing import Any

from edge_depth.errors import ConfigError

BUNDLE = "bundle"  # a setting taken from the bundle's model.json
MEDIAN_PATTERNS = ("9x9/2", "13x13/3", "9x9/4")
FIT, NATIVE, BUDGET = "fit", "native", "budget"
SCALE_WORDS = (FIT, BUDGET, NATIVE)
# where a bundle declares nothing
UNDECLARED = {"edge_median": "off"}
# options the engine had and no longer has -> why (a config naming one is refused with this)
REMOVED = {
    "match_photometry": "the band refinement's census cost is blind to the grey-level "
                        "differences it matched (docs/results.md); delete the key",
    "edge_select": "on frames without LiDAR points the band refinement does better without "
                   "it (docs/results.md); delete the key",
    **{key: "the band refinement took the edge matching's place (docs/results.md); delete "
            "the key" for key in ("edge_match", "edge_match_rows", "edge_matcher",
                                  "edge_match_far_px")},
}


def _option(default: Any, doc: str, choices: tuple | None = None,
            bounds: tuple | None = None) -> Any:
    return field(default=default, metadata=dict(doc=doc, choices=choices, bounds=bounds))


@dataclass(frozen=True)
class EngineOptions:
    """The engine's settings (defaults: the shipped bundle as it was made to run)."""

    bundle: str = _option("", 'the model bundle directory; "" = the shipped one')
    precision: str = _option("auto", "the bundle's graphs to run; auto: int8 where this CPU "
                             "runs it faster (int8 dot products: VNNI, AMX, ARM dotprod; or "
                             "OpenVINO, whose int8 kernels win without them), else fp32",
                             choices=("auto", "int8", "fp32"))
    runtime: str = _option("auto", "auto: OpenVINO on x86-64 where installed, else ONNX Runtime",
                           choices=("auto", "onnxruntime", "openvino"))
    bf16: str = _option("auto", "OpenVINO: the encoder in bf16; auto = where the CPU has it "
                        "natively (AVX512-BF16, AMX)", choices=("auto", "on", "off"))
    int8_encoder: str = _option("auto", "int8 precision: the bundle's int8 encoder instead of "
                                "its float one; auto = on OpenVINO where that would run in f32 "
                                "on a CPU without int8 dot products (AVX2-only x86)",
                                choices=("auto", "on", "off"))
    threads: int = _option(2, "the engine's threads", bounds=(1, 256))
    scale: float | str = _option(BUDGET, 'the camera\'s images as the network sees them: '
                                 '"budget" (the largest factor ≤ 1 that keeps the bundle\'s '
                                 "pixel count, at the camera's aspect; on a bundle of one size: "
                                 '"fit"), "fit" (the largest factor ≤ 1 that fits the '
                                 "bundle's width and height), \"native\" (the camera's own "
                                 "size, a bundle with any-size graphs), or a factor in (0, 1] "
                                 "within the bundle's size")
    iters: int = _option(0, "GRU iterations per frame; 0 = the bundle's (the shipped one: 3)",
                         bounds=(0, 64))
    deadline_ms: float = _option(0.0, "stop iterating before the step that would end after "
                                 "this (ms from the frame's start), and skip the band "
                                 "refinement where it would end after it (as its recent "
                                 "times predict; tried again after 10 skips); 0 = no "
                                 "deadline",
                                 bounds=(0.0, 60_000.0))
    denoise_lidar: bool = _option(False, "a noisy LiDAR map (its points off the line through "
                                  "their row neighbours by more than 0.3 px, robustly) "
                                  "smoothed along its rows, depth edges kept (docs/results.md: "
                                  "1-21 % at 0.75-1.5 px of noise)")
    align_lidar: bool = _option(True, "a LiDAR map that sits off the image (a calibration "
                                "off by a fraction of a degree) moved back by the offset at "
                                "which its depth edges meet the left image's edges")
    pipelined: bool = _option(False, "live: rectification, the engine and logging overlap in "
                              "threads (more frames/s at a higher latency)")
    lidar_select: bool = _option(True, "the bundle's per-cell choice between the network and "
                                 "the nearest LiDAR point, if it has one")
    rate: str = _option("lidar", "lidar: the engine on every frame it is given; camera (an "
                        "experiment, a spinning LiDAR paired by \"nearest\"): the engine on "
                        "key frames (a fresh scan, or where the optical flow is lost) and, on "
                        "the frames between, the key frame's depth carried along the flow "
                        "(~5 ms a frame; edge.runtime.propagate), without waiting for the "
                        "next scan", choices=("lidar", "camera"))
    refine: str = _option("band", "band: the network's estimate refined by semi-global "
                          "matching in a band around it as wide as its confidence says, the "
                          "LiDAR and the network guiding the cost, then the weighted median "
                          "over its unsure edges (edge.runtime.band_sgm); off: the median "
                          "alone on the network's estimate (faster, less accurate: "
                          "docs/results.md)", choices=("off", "band"))
    edge_median: str = _option(BUNDLE, "the grey-guided weighted median over the network's "
                               "unsure edges after the band refinement "
                               '(window/step), or off; "bundle" (the shipped one: 9x9/2)',
                               choices=(BUNDLE, "off", *MEDIAN_PATTERNS))

    def __post_init__(self) -> None:
        for f in fields(self):
            value, choices, bounds = (getattr(self, f.name), f.metadata["choices"],
                                      f.metadata["bounds"])
            if choices and value not in choices:
                raise ConfigError(f.name, " | ".join(map(str, choices)), value)
            if bounds and not (isinstance(value, (int, float)) and not isinstance(value, bool)
                               and bounds[0] <= value <= bounds[1]):
                raise ConfigError(f.name, f"{bounds[0]}–{bounds[1]}", value)
        scale = self.scale
        if scale not in SCALE_WORDS and not (
                isinstance(scale, (int, float)) and not isinstance(scale, bool)
                and 0 <= scale <= 1):
            raise ConfigError("scale", '"fit", "budget", "native" or a factor in (0, 1]', scale)

    @property
    def bf16_choice(self) -> bool | None:
        """bf16 for the backends: None = where the CPU has it."""
        return {"auto": None, "on": True, "off": False}[self.bf16]

    def resolved(self, declared: dict) -> EngineOptions:
        """These options with every "bundle" field taken from the bundle's preset
        (`bundle_preset`)."""
        return replace(self, **{k: declared[k] for k in UNDECLARED
                                if getattr(self, k) == BUNDLE})

    def from_bundle(self) -> bool:
        """Whether the median's setting is the bundle's own (for the engine's log line)."""
        return self.edge_median == BUNDLE

    @classmethod
    def with_overrides(cls, base: EngineOptions | None = None, **given: Any) -> EngineOptions:
        """`base` (default: the defaults) with the given fields; None leaves a field as it
        is, and the Python spellings callers use are accepted: bf16 True/False, scale 0
        (= "fit")."""
        values = {k: v for k, v in given.items() if v is not None}
        if isinstance(values.get("bf16"), bool):
            values["bf16"] = "on" if values["bf16"] else "off"
        if values.get("scale") == 0:
            values["scale"] = FIT
        if "bundle" in values:
            values["bundle"] = str(values["bundle"])
        return replace(base or cls(), **values)


def bundle_preset(meta: dict, bundle: str = "") -> dict:
    """The settings a bundle was made for (model.json's "engine", written by tools/export.py)
    over UNDECLARED; ConfigError naming the bundle when a value is not one the engine takes
    (a hand-edited model.json)."""
    declared = meta.get("engine") or {}
    if not isinstance(declared, dict):
        raise ConfigError("bundle", 'model.json\'s "engine" as a table of settings',
                          f"{declared!r} in {bundle}")
    values = {**UNDECLARED, **{k: v for k, v in declared.items() if k in UNDECLARED}}
    try:
        if BUNDLE in values.values():
            raise ConfigError(next(k for k, v in values.items() if v == BUNDLE),
                              'a setting, not "bundle"', BUNDLE)
        EngineOptions(**values)
    except ConfigError as exc:
        raise ConfigError("bundle", f"model.json's engine.{exc.key} {exc.expected}",
                          f"{exc.got!r} in {bundle}") from None
    return values


def _flag_type(f) -> Any:
    default = f.default
    if f.name == "scale":
        return _scale_value
    return type(default)


def _scale_value(text: str) -> float | str:
    if text in SCALE_WORDS:
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected "fit", "budget", "native" or a factor in '
                                         f"(0, 1], got {text!r}") from None


def flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def add_engine_arguments(parser: argparse.ArgumentParser, only: tuple[str, ...] | None = None,
                         **defaults: Any) -> None:
    """One flag per EngineOptions field (or those in `only`), each with the field's doc; a
    flag not given is None (the field's default, or the config file's value, stands).
    `defaults` changes what the help says the default is (fleet: threads 1)."""
    for f in fields(EngineOptions):
        if only is not None and f.name not in only:
            continue
        default = defaults.get(f.name, f.default)
        help_ = f"{f.metadata['doc']} (default: {default!r})".replace("%", "%%")  # argparse's
        if isinstance(f.default, bool):
            parser.add_argument(flag(f.name), action=argparse.BooleanOptionalAction,
                                default=None, help=help_)
        else:
            parser.add_argument(flag(f.name), type=_flag_type(f), default=None,
                                choices=f.metadata["choices"], help=help_,
                                metavar=None if f.metadata["choices"] else f.name.upper())


def options_from_args(args: argparse.Namespace, base: EngineOptions | None = None,
                      only: tuple[str, ...] | None = None, **defaults: Any) -> EngineOptions:
    """The EngineOptions the flags of `add_engine_arguments` ask for (those in `only`, as it
    was given them), over `base` (and `defaults` for flags not given)."""
    given = {f.name: getattr(args, f.name, None) for f in fields(EngineOptions)
             if only is None or f.name in only}
    return EngineOptions.with_overrides(
        EngineOptions.with_overrides(base, **defaults), **given)


def reference_table() -> str:
    """The `[engine]` keys as a markdown table (docs/configuration.md holds it verbatim)."""
    rows = ["| key | default | what it does |", "|---|---|---|"]
    for f in fields(EngineOptions):
        choices = f.metadata["choices"]
        what = f.metadata["doc"] + (f" (one of: {', '.join(map(str, choices))})" if choices
                                    else "")
        rows.append(f"| `{f.name}` | `{f.default!r}` | {what} |")
    return "\n".join(rows)
