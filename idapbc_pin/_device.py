"""The torch device a command asked for, checked against what torch sees here."""

from __future__ import annotations

import torch

from .errors import IdapbcError

__all__ = ["require_device"]


def require_device(device: str) -> torch.device:
    """`device` as a torch device that exists here, else a one-line `IdapbcError` with the fix."""
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise IdapbcError(f"unknown device '{device}' ({str(exc).splitlines()[0][:80]}). Fix: use cpu, cuda or cuda:N.") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise IdapbcError(f"device '{device}' requested but torch sees no CUDA device. Fix: use --device cpu.")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise IdapbcError(f"device '{device}' requested but torch sees {torch.cuda.device_count()} CUDA device(s). Fix: use cuda:0 … cuda:{torch.cuda.device_count() - 1}.")
    elif dev.type != "cpu":
        raise IdapbcError(f"device '{device}' is not supported. Fix: use cpu, cuda or cuda:N.")
    return dev
