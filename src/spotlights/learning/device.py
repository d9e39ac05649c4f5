"""Torch device selection with one-line errors."""

from __future__ import annotations

import os

import torch

from ..errors import ParameterError


def default_device() -> torch.device:
    """CUDA when available (this process's local rank under torchrun), else CPU."""
    if torch.cuda.is_available():
        return torch.device("cuda", int(os.environ.get("LOCAL_RANK", 0)))
    return torch.device("cpu")


def resolve_device(device=None) -> torch.device:
    """The torch device to use: ``device`` if given (validated), else CUDA when available, else CPU.

    Raises :class:`ParameterError` for an unknown device string, or a CUDA or MPS device on a machine
    without it (naming the devices that are available).
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
    elif dev.type == "mps":
        if not mps_available():
            raise ParameterError(
                f"device {device!r} asked for, but MPS (Apple GPU) is not available on this machine "
                f"(available: {', '.join(available_devices())})"
            )
    elif dev.type != "cpu":
        raise ParameterError(f"unsupported torch device {device!r} (use cpu, cuda or cuda:N)")
    return dev


def mps_available() -> bool:
    """Whether this torch can run on an Apple GPU (MPS): built with it, on a Mac that has one."""
    mps = getattr(torch.backends, "mps", None)
    try:
        return bool(mps is not None and mps.is_available())
    except RuntimeError:  # pragma: no cover - a torch that cannot even ask
        return False


def available_devices() -> list[str]:
    """The device names :func:`resolve_device` accepts here: ``cpu``, then ``cuda:0``... and ``mps`` when present."""
    names = ["cpu"]
    if torch.cuda.is_available():
        names += [f"cuda:{i}" for i in range(torch.cuda.device_count())]
    if mps_available():
        names.append("mps")
    return names


PRECISIONS = ("auto", "fp32", "bf16")
"""Training precisions offered by ``spotlights train --precision`` (``fp16`` is what ``bf16``
becomes on a CUDA device without bfloat16 support; it runs with a gradient scaler)."""


def cpu_supports_bf16() -> bool:
    """True when this CPU has native bfloat16 matrix instructions (AVX512-BF16 or AMX-BF16).

    oneDNN's own check is used when torch exposes it, else the Linux CPU flags. Without native
    support torch still runs bfloat16 on the CPU, emulated and slower than float32.
    """
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        pass
    try:
        with open("/proc/cpuinfo") as f:
            flags = f.read()
    except OSError:
        return False
    return "avx512_bf16" in flags or "amx_bf16" in flags


def resolve_precision(precision: str | None, device: torch.device) -> str:
    """The precision a run uses: ``"fp32"``, ``"bf16"`` or ``"fp16"`` (CUDA only).

    ``"auto"`` (or None): bf16 on a CUDA device that supports it, else fp16 on CUDA; on the CPU,
    bf16 where the CPU has native bfloat16 instructions, else fp32. ``"bf16"`` on a CUDA device
    without bfloat16 support becomes fp16 (with a gradient scaler). Raises :class:`ParameterError`
    for anything else.
    """
    p = "auto" if precision is None else str(precision).lower()
    if p not in PRECISIONS:
        raise ParameterError(f"unknown precision {precision!r} (choose {', '.join(PRECISIONS)})")
    if p == "fp32":
        return "fp32"
    if device.type == "cuda":
        return "bf16" if torch.cuda.is_bf16_supported() else "fp16"
    if device.type == "cpu":
        return "bf16" if (p == "bf16" or cpu_supports_bf16()) else "fp32"
    return "fp32" if p == "auto" else "bf16"


def autocast(precision: str, device: torch.device):
    """A context manager running the forward pass at ``precision`` (``fp32``: no autocast).

    Weights stay float32 (the master copy the optimizer updates); matrix products run in
    bfloat16 / float16 under ``torch.autocast``. Cast outputs back with ``.float()`` before
    losses and metrics.
    """
    import contextlib

    if precision == "fp32":
        return contextlib.nullcontext()
    dtype = torch.bfloat16 if precision == "bf16" else torch.float16
    return torch.autocast(device_type=device.type, dtype=dtype)
