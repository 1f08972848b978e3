"""Checkpoints as safetensors: weights, optimiser state, step and the resolved config.

Everything needed to resume or to run inference is in one file; the config and the package
version sit in its metadata. Writes go to a temporary file that is renamed when complete.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import torch
from safetensors import SafetensorError, safe_open
from safetensors.torch import load_file, save_file

from hybrid import __version__
from hybrid.types import InputError


def save_checkpoint(path: Path, modules: dict[str, torch.nn.Module], config: dict,
                    step: int, optimizer: torch.optim.Optimizer | None = None,
                    kind: str = "depth", extra: dict[str, str] | None = None) -> None:
    """Write modules' weights (and the optimiser's state) to path atomically; `extra`
    entries join the metadata."""
    tensors = {f"{name}.{k}": v.detach().cpu().contiguous()
               for name, module in modules.items() for k, v in module.state_dict().items()}
    meta = {"kind": kind, "config": json.dumps(config), "step": str(step),
            "c2d2_version": __version__, **(extra or {})}
    if optimizer is not None:
        state = optimizer.state_dict()
        for index, values in state["state"].items():
            for key, value in values.items():
                tensors[f"optimizer.{index}.{key}"] = torch.as_tensor(value).cpu().contiguous()
        meta["optimizer_groups"] = json.dumps(state["param_groups"])
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    save_file(tensors, str(tmp), metadata=meta)
    os.replace(tmp, path)


def read_checkpoint(path: Path, kind: str = "depth") -> tuple[dict[str, torch.Tensor], dict]:
    """Tensors and metadata (config parsed) of a checkpoint; checks its kind."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"checkpoint not found: {path}")
    try:
        tensors = load_file(str(path))
        with safe_open(str(path), "pt") as handle:
            meta = dict(handle.metadata() or {})
    except (SafetensorError, OSError) as err:
        raise InputError(f"cannot read checkpoint {path}: {err}") from err
    if meta.get("kind") != kind:
        raise InputError(f"{path} is a {meta.get('kind')!r} checkpoint, not a {kind!r} one")
    meta["config"] = json.loads(meta["config"])
    meta["step"] = int(meta["step"])
    return tensors, meta


def checkpoint_metadata(path: Path) -> dict[str, str]:
    """A checkpoint's metadata as stored (its header only; read_checkpoint checks the file)."""
    with safe_open(str(path), "pt") as handle:
        return dict(handle.metadata() or {})


def load_modules(tensors: dict[str, torch.Tensor], modules: dict[str, torch.nn.Module],
                 path: Path) -> None:
    """Load each module's weights from the checkpoint's tensors, with a clear error."""
    for name, module in modules.items():
        prefix = f"{name}."
        state = {k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)}
        try:
            module.load_state_dict(state)
        except RuntimeError as err:
            raise InputError(f"{path}: weights of {name!r} do not fit this network (a checkpoint "
                             f"of another preset?): {str(err).splitlines()[0]}") from err


def load_model(path: Path, kind: str, config_cls, build, preset: str | None = None
               ) -> torch.nn.Module:
    """A model saved by save_checkpoint, in eval mode: build(config) with the config read from
    the file, then the weights of each of its child modules; checks its preset if given."""
    tensors, meta = read_checkpoint(path, kind)
    config = config_cls.from_dict(meta["config"])
    if preset is not None and config.preset != preset:
        raise InputError(f"{path} is a {config.preset!r}-preset {kind} model, but the "
                         f"{preset!r} preset was asked for")
    model = build(config)
    load_modules(tensors, dict(model.named_children()), path)
    return model.eval()


def load_optimizer(tensors: dict[str, torch.Tensor], meta: dict,
                   optimizer: torch.optim.Optimizer) -> None:
    state: dict[int, dict[str, torch.Tensor]] = {}
    for key, value in tensors.items():
        if key.startswith("optimizer."):
            _, index, name = key.split(".", 2)
            state.setdefault(int(index), {})[name] = value
    optimizer.load_state_dict({"state": state,
                               "param_groups": json.loads(meta["optimizer_groups"])})


def export_weights(checkpoint: Path, dest: Path, kind: str = "depth") -> Path:
    """Copy a training checkpoint without its optimiser state (what is shipped)."""
    tensors, meta = read_checkpoint(checkpoint, kind)
    weights = {k: v for k, v in tensors.items() if not k.startswith("optimizer.")}
    meta = {"kind": kind, "config": json.dumps(meta["config"]), "step": str(meta["step"]),
            "c2d2_version": meta.get("c2d2_version", __version__)}
    dest = Path(dest)
    tmp = dest.with_name(dest.name + ".tmp")
    save_file(weights, str(tmp), metadata=meta)
    os.replace(tmp, dest)
    return dest


def file_tag(path: Path) -> str:
    """First 12 hex digits of a file's SHA-256."""
    if not Path(path).is_file():
        raise InputError(f"file not found: {path}")
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12]
