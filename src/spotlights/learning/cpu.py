"""What this CPU offers the models, read without torch: its name, its flags, and the precision ``auto`` picks.

The Linux CPU flags (``/proc/cpuinfo``) say whether bfloat16 matrix products run natively: ``avx512_bf16``
(AVX512-BF16, e.g. AMD Zen 4, Intel Cooper Lake and later) or ``amx_bf16`` (Intel AMX tiles, Sapphire Rapids
and later). Without them torch still runs bfloat16 on the CPU, emulated and slower than float32, so
``--precision auto`` stays float32 there. Every function takes the flags as an argument, so that the choice
can be tested for any CPU.
"""

from __future__ import annotations

import os
from collections.abc import Iterable

CPUINFO = "/proc/cpuinfo"
BF16_FLAGS = ("avx512_bf16", "amx_bf16")
"""CPU flags of native bfloat16 matrix instructions (either is enough)."""
AMX_FLAGS = ("amx_tile", "amx_bf16", "amx_int8")


def _cpuinfo(path: str | os.PathLike = CPUINFO) -> str:
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            return f.read()
    except OSError:
        return ""


def cpu_flags(path: str | os.PathLike = CPUINFO) -> frozenset[str]:
    """The CPU's feature flags (the first ``flags`` line of ``path``, Linux's ``/proc/cpuinfo``); empty where
    there is no such file (another OS: then ``auto`` keeps float32)."""
    for line in _cpuinfo(path).splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("flags", "Features"):
            return frozenset(value.split())
    return frozenset()


def cpu_model(path: str | os.PathLike = CPUINFO) -> str:
    """The CPU's model name (``model name`` of ``path``), or ``"unknown"``."""
    for line in _cpuinfo(path).splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "model name" and value.strip():
            return value.strip()
    return "unknown"


def has_bf16(flags: Iterable[str] | None = None) -> bool:
    """Whether a CPU with ``flags`` (default: this one's, :func:`cpu_flags`) multiplies bfloat16 matrices natively
    (:data:`BF16_FLAGS`)."""
    f = cpu_flags() if flags is None else frozenset(flags)
    return any(name in f for name in BF16_FLAGS)


def cpu_description(flags: Iterable[str] | None = None, model: str | None = None) -> dict:
    """The CPU as speed results name it: ``model``, ``avx512f``, ``avx512_bf16``, ``amx`` (any AMX flag) and
    ``cores`` (CPUs this process may use)."""
    f = cpu_flags() if flags is None else frozenset(flags)
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        cores = os.cpu_count() or 1
    return {
        "model": cpu_model() if model is None else model,
        "avx512f": "avx512f" in f,
        "avx512_bf16": "avx512_bf16" in f,
        "amx": any(a in f for a in AMX_FLAGS),
        "cores": cores,
    }


def auto_precision(runtime: str, device_type: str = "cpu", flags: Iterable[str] | None = None) -> str:
    """The precision ``--precision auto`` runs a model at: ``"fp32"`` with onnxruntime (the exports are float32)
    and on a CPU without native bfloat16 (:func:`has_bf16` of ``flags``), ``"bf16"`` with torch on a CPU that has
    it; ``"auto"`` on another device (CUDA: torch chooses bf16 or fp16,
    :func:`spotlights.learning.device.resolve_precision`)."""
    if runtime == "onnx":
        return "fp32"
    if device_type != "cpu":
        return "auto"
    return "bf16" if has_bf16(flags) else "fp32"


__all__ = ["BF16_FLAGS", "auto_precision", "cpu_description", "cpu_flags", "cpu_model", "has_bf16"]
