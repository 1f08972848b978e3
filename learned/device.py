"""The torch device the networks run on, chosen by name: auto, cpu, cuda or cuda:N."""

from __future__ import annotations

import torch
from torch import nn

from hybrid.types import InputError


def pick_device(name: str = "auto") -> torch.device:
    """The device called `name`; an error naming what to do when it is not there."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError as err:
        raise InputError(f"--device {name!r}: expected auto, cpu, cuda or cuda:N") from err
    if device.type not in ("cpu", "cuda"):
        raise InputError(f"--device {name!r}: expected auto, cpu, cuda or cuda:N")
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if (device.index or 0) >= count:
            raise InputError(f"--device {name!r}: torch {torch.__version__} sees {count} CUDA "
                             f"device(s); use --device cpu, or install a CUDA build of torch")
    return device


def device_of(module: nn.Module) -> torch.device:
    """The device a module's weights live on."""
    return next(module.parameters()).device
