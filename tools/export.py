"""Export a training checkpoint to an ONNX bundle the engine runs without torch.

    python tools/export.py CHECKPOINT --out BUNDLE_DIR [--size 640x400]

Three graphs (opset 17; height and width dynamic, so one bundle runs any camera at its own
size: model.json's "any_size") so the iteration count stays a runtime choice:
encoder.onnx (features, correlation pyramid, context, affinity, the first CSPN),
step.onnx (lookup, GRU step, Δd, CSPN with re-injection; run K times) and upsample.onnx
(the upsampling-mask head and convex upsampling, run once on the last step's output; with
the confidence head it returns the confidence 0-1 as well),
plus model.json (input size, downsample factor, FLOPs per graph, the checkpoint's training
summary, and with the confidence head the engine's default median, "engine"). The export
is checked: ONNX Runtime against PyTorch on a synthetic scene at 4 iterations, at `--size`
and at a second size of another aspect (whose 1/8 width is odd).
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np

from edge_depth.arguments import parse_size

ENCODER_INPUTS = ["left", "right", "sparse", "valid"]
# the context enters the step as the GRU's two fixed terms, computed once per frame by the
# encoder graph (`UpdateBlock.context_terms`; older bundles fed "context" itself,
# and the engine runs both: it feeds the step whatever it asks for by name)
STATE = ["corr", "context_zr", "context_q", "weights", "centre", "sparse_low", "valid_low"]
STEP_INPUTS = ["disparity", "hidden", *STATE]
STEP_OUTPUTS = ["disparity_out", "hidden_out"]
UPSAMPLE_INPUTS = ["disparity", "hidden"]
OPSET = 17
# the graphs' dynamic axes: full-resolution inputs (h, w), 1/8 state (h8, w8), and the
# flattened correlation pyramid, whose last axis grows with the width
FULL, LOW = {2: "height", 3: "width"}, {2: "height_8", 3: "width_8"}
DYNAMIC = {name: LOW for name in ["disparity", "hidden", *STATE]} | {
    name: FULL for name in ENCODER_INPUTS} | {
    "corr": {1: "height_8", 2: "width_8", 3: "pyramid"},
    "disparity_out": LOW, "hidden_out": LOW, "disparity_full": FULL,
    "confidence": {2: "confidence_height", 3: "confidence_width"}}
# the confidence head (convex upsampling, a 1/8 confidence) is trained to hand its unsure
# edges to the refinement after it, so its bundles declare the weighted median over them as
# the engine's default in model.json's "engine" (config and command line still override it;
# docs/results.md)
MATCHED_ENGINE = {"edge_median": "9x9/2"}
# the GRU steps a bundle runs at by default (model.json's default_iters): the shipped one's,
# with the band refinement after them (docs/results.md)
DEFAULT_ITERS = 3


def build_graphs(net):
    """Wrap a SparseStereoNet (gru_levels 1) in the three exportable modules."""
    import torch

    from edge_depth.model.network import convex_upsample

    if net.config.gru_levels != 1:
        raise SystemExit("export supports gru_levels 1 (the deployed configuration)")

    class Encoder(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.net = net

        def forward(self, left, right, sparse, valid):
            s = self.net.encode(left, right, sparse, valid)
            context_zr, context_q = self.net.update.context_terms(s["context"])
            return (s["disparity"], s["hidden"], s["corr"], context_zr, context_q, s["weights"],
                    s["centre"], s["sparse"], s["valid"])

    class Step(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.net = net

        def forward(self, disparity, hidden, corr, context_zr, context_q, weights, centre,
                    sparse, valid):
            state = dict(corr=corr, context_zr=context_zr, context_q=context_q,
                         weights=weights, centre=centre, sparse=sparse, valid=valid)
            d, h, _, _ = self.net.step(state, disparity, hidden, hidden[:, :0])
            return d, h

    class Upsample(torch.nn.Module):
        """The mask head runs here, once per frame, on the last step's hidden state: only the
        last step's mask is used, so the step graph does not compute it."""

        def __init__(self):
            super().__init__()
            self.net = net

        def forward(self, disparity, hidden):
            mask = self.net.update.upsampling_mask(hidden)
            return convex_upsample(disparity, mask, self.net.config.downsample)

    class UpsampleConfidence(torch.nn.Module):
        """Convex upsampling with the confidence head: (disparity, confidence 0-1)."""

        def __init__(self):
            super().__init__()
            self.net = net

        def forward(self, disparity, hidden):
            mask = self.net.update.upsampling_mask(hidden)
            full, logit = self.net.upsample(disparity, mask, hidden)
            return full, torch.sigmoid(logit)

    upsample = UpsampleConfidence() if net.config.refine else Upsample()
    return Encoder().eval(), Step().eval(), upsample.eval()


def count_flops(module, args) -> float:
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        module(*args)
    return float(counter.get_total_flops())


def load_checkpoint(path: Path):
    import torch

    from edge_depth.model.config import ModelConfig
    from edge_depth.model.network import SparseStereoNet

    ckpt = torch.load(path, map_location="cpu", weights_only=False)
    net = SparseStereoNet(ModelConfig.from_dict(ckpt["config"]))
    net.load_state_dict(ckpt["model"])
    return net.eval(), ckpt


def reference_inputs(size: tuple[int, int], seed: int = 1_000_000) -> dict[str, np.ndarray]:
    """A synthetic test-split scene at `size` (the export check's input)."""
    from edge_depth.sim import RigConfig, make_sample

    w, h = size
    sample = make_sample(seed, RigConfig(width=w, height=h), "beams16")
    sparse, valid = sample.sparse_disparity("left")
    return {k: v.astype(np.float32)[None, None] for k, v in
            dict(left=sample.left, right=sample.right, sparse=sparse * valid,
                 valid=valid.astype(np.float32)).items()}


def export(checkpoint: Path, out: Path, size: tuple[int, int],
           default_iters: int = DEFAULT_ITERS, check: bool = True) -> dict:
    import torch

    net, ckpt = load_checkpoint(checkpoint)
    cfg = net.config
    w, h = size
    if w % cfg.downsample or h % cfg.downsample:
        raise SystemExit(f"--size {w}x{h}: both sides must be multiples of {cfg.downsample}")
    out.mkdir(parents=True, exist_ok=True)
    encoder, step, upsample = build_graphs(net)
    x = torch.zeros(1, 1, h, w)
    with torch.no_grad():
        d, hidden, *state = encoder(x, x, x, x)
        step_args = (d, hidden, *state)
        up_args = (d, hidden)
        graphs = [
            ("encoder.onnx", encoder, (x, x, x, x), ENCODER_INPUTS,
             ["disparity", "hidden", *STATE]),
            ("step.onnx", step, step_args, STEP_INPUTS, STEP_OUTPUTS),
            ("upsample.onnx", upsample, up_args, UPSAMPLE_INPUTS,
             ["disparity_full", "confidence"] if cfg.refine else ["disparity_full"]),
        ]
        for name, module, args, inputs, outputs in graphs:
            with warnings.catch_warnings():  # the tracer's notes on constants the graphs
                warnings.simplefilter("ignore", torch.jit.TracerWarning)  # mean to have,
                warnings.filterwarnings("ignore", "Constant folding")  # not for users
                warnings.simplefilter("ignore", DeprecationWarning)  # the legacy exporter's
                torch.onnx.export(module, args, str(out / name), input_names=inputs,
                                  output_names=outputs, opset_version=OPSET, dynamo=False,
                                  dynamic_axes={k: DYNAMIC[k] for k in inputs + outputs})
        flops = dict(encoder=count_flops(encoder, (x, x, x, x)),
                     step=count_flops(step, step_args),
                     upsample=count_flops(upsample, up_args))
    flops["iters_4"] = flops["encoder"] + 4 * flops["step"] + flops["upsample"]
    training = ckpt.get("training") or {}
    if not training and "args" in ckpt:
        training = {k: v for k, v in ckpt["args"].items() if isinstance(v, (int, float, str))}
    meta = dict(
        format=1, size=[w, h], any_size=True, downsample=cfg.downsample,
        default_iters=default_iters,
        config=cfg.to_dict(), opset=OPSET,
        flops=flops,
        params=int(sum(p.numel() for p in net.parameters())),
        checkpoint=checkpoint.name, step=int(ckpt.get("step", 0)), training=training,
        precisions={"fp32": {"encoder": "encoder.onnx", "step": "step.onnx",
                             "upsample": "upsample.onnx"}},
    )
    if cfg.refine:  # the engine's default for this bundle (Engine reads it)
        meta["engine"] = dict(MATCHED_ENGINE)
    if check:
        meta["export_check"] = check_export(net, out, meta, size)
    (out / "model.json").write_text(json.dumps(meta, indent=2))
    return meta


def check_export(net, bundle: Path, meta: dict, size: tuple[int, int]) -> dict:
    """Max |ONNX Runtime - PyTorch| disparity (px) at 4 iterations on a synthetic scene at
    `size`, and ("other_size") at another size run at its own resolution: a value the trace
    kept as the export size's constant would show there."""
    from edge_depth.runtime.engine import Engine

    step = meta["downsample"]
    other = ((size[0] * 3 // 4) // (2 * step) * 2 * step + step,
             (size[1] * 3 // 4) // step * step)
    check = {}
    for at, scale in ((size, "fit"), (other, "native")):
        inputs = reference_inputs(at)
        # the graphs against torch: the network alone
        engine = Engine(bundle, precision="fp32", threads=2, meta=meta, runtime="onnxruntime",
                        refine="off", edge_median="off", scale=scale)
        got = engine.infer(inputs["left"][0, 0], inputs["right"][0, 0],
                           inputs["sparse"][0, 0], iters=4).disparity
        diff = np.abs(got - torch_disparity(net, inputs))
        check[at] = dict(iters=4, max_abs_px=float(diff.max()), mean_abs_px=float(diff.mean()))
    return dict(check[size], other_size=dict(size=list(other), **check[other]))


def torch_disparity(net, inputs: dict[str, np.ndarray], iters: int = 4) -> np.ndarray:
    import torch

    with torch.no_grad():
        return net(*(torch.from_numpy(inputs[k]) for k in ENCODER_INPUTS),
                   iters)[-1][0, 0].numpy()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--out", type=Path, required=True, help="bundle directory")
    p.add_argument("--size", type=parse_size, default=(640, 400),
                   help="the bundle's size, WIDTHxHEIGHT: its pixel budget (\"budget\", "
                   "the engine's default, and \"fit\" scale a camera to it; \"native\" runs "
                   "any size), default 640x400")
    p.add_argument("--iters", type=int, default=DEFAULT_ITERS,
                   help="the engine's default GRU iterations (a runtime choice), default "
                        f"{DEFAULT_ITERS}")
    p.add_argument("--no-check", action="store_true", help="skip the ONNX Runtime check")
    args = p.parse_args(argv)
    if not args.checkpoint.is_file():
        p.error(f"{args.checkpoint}: no such checkpoint")
    size = args.size
    meta = export(args.checkpoint, args.out, size, args.iters, check=not args.no_check)
    print(f"wrote {args.out} ({meta['params']} parameters, "
          f"{meta['flops']['iters_4'] / 1e9:.1f} GFLOP at {size[0]}x{size[1]}, 4 iterations)")
    if "export_check" in meta:
        c = meta["export_check"]
        o = c["other_size"]
        print(f"ONNX Runtime vs PyTorch at 4 iterations: max {c['max_abs_px']:.5f} px, "
              f"mean {c['mean_abs_px']:.6f} px; at {o['size'][0]}x{o['size'][1]} (its own "
              f"size) max {o['max_abs_px']:.5f} px")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
