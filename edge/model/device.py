"""Where the network trains: a --device value as a torch device, and tensors moved between
devices (`tools/train.py`, `edge-depth adapt`)."""

from __future__ import annotations

import torch


def resolve_device(name: str) -> torch.device:
    """A --device value as a torch device: auto (the GPU when torch sees one), cpu, cuda or
    cuda:N. One the machine lacks is a ValueError with one clear line."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError:
        raise ValueError(f"--device {name}: not a device (auto, cpu, cuda or cuda:N)") from None
    if device.type not in ("cpu", "cuda"):
        raise ValueError(f"--device {name}: only cpu and cuda are supported")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"--device {name}: this torch sees no CUDA GPU "
                         f"(torch {torch.__version__}; use --device cpu)")
    if device.type == "cuda" and (device.index or 0) >= torch.cuda.device_count():
        raise ValueError(f"--device {name}: torch sees {torch.cuda.device_count()} GPU(s)")
    return device


def on_cpu(value):
    """A state dict (or a nest of them) with every tensor on the CPU: checkpoints load on any
    machine, a robot's included, whatever trained them."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu()
    if isinstance(value, dict):
        return {k: on_cpu(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(on_cpu(v) for v in value)
    return value


def to_device(batch: dict, device: torch.device) -> dict:
    return {k: v.to(device, non_blocking=True) if isinstance(v, torch.Tensor) else v
            for k, v in batch.items()}
