"""Torch device selection with one-line errors."""

from __future__ import annotations

import torch

from ..errors import ParameterError


def resolve_device(device=None) -> torch.device:
    """The torch device to use: ``device`` if given (validated), else CUDA when available, else CPU.

    Raises :class:`ParameterError` for an unknown device string or a CUDA device on a machine
    without CUDA.
    """
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if isinstance(device, torch.device):
        dev = device
    else:
        try:
            dev = torch.device(str(device))
        except (RuntimeError, ValueError):
            raise ParameterError(f"unknown torch device {device!r} (use cpu, cuda or cuda:N)") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ParameterError(f"device {device!r} asked for, but CUDA is not available on this machine")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ParameterError(f"device {device!r}: only {torch.cuda.device_count()} CUDA device(s) here")
    elif dev.type not in ("cpu", "mps"):
        raise ParameterError(f"unsupported torch device {device!r} (use cpu, cuda or cuda:N)")
    return dev
