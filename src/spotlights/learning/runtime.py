"""The runtime choice: a completer from a checkpoint name or file, run with torch or with onnxruntime.

:func:`load_completer` is the one place that decides which runtime runs a model (``spotlights complete``,
``real complete`` and the public :func:`spotlights.load_completer` call it): a ``.onnx`` file (a
``spotlights export``) runs with onnxruntime (:class:`~spotlights.learning.export.OnnxCompleter`), anything
else (a checkpoint file, ``"default"``, ``"paper"``, ``"classes"``) with torch (:class:`~spotlights.learning.inference.Completer`).
Neither runtime is imported before it is needed.
"""

from __future__ import annotations

import numbers
import os
from typing import Literal

from ..errors import ParameterError
from .export import load_onnx_completer
from .inference import BaseCompleter
from .inference import load_completer as load_torch_completer

RUNTIMES = ("torch", "onnx")

Runtime = Literal["torch", "onnx"]


def load_completer(
    name_or_path: str | os.PathLike | None = "default",
    runtime: Runtime | None = None,
    device: str | None = None,
    precision: str | None = "fp32",
    threads: int | None = None,
) -> BaseCompleter:
    """A completion model ready for inference.

    Parameters
    ----------
    name_or_path : a checkpoint file (``.pt``), a short name (``"default"``: the package's default model;
        ``"paper"``: the paper-faithful SA-Net; None = ``"default"``) or a ``spotlights export`` ``.onnx`` file.
    runtime : ``"torch"`` or ``"onnx"``; None (default) picks onnx for a ``.onnx`` file, torch otherwise.
    device : torch device or name (torch runtime; default CUDA when available, else CPU).
    precision : torch runtime: ``"fp32"`` (default), ``"bf16"`` or ``"auto"``; an ONNX model runs as exported.
    threads : onnx runtime: onnxruntime's intra-op threads, >= 1 (None: its default); the torch runtime's threads are
        the process's (``torch.set_num_threads``).

    Returns a :class:`~spotlights.learning.inference.BaseCompleter` (a torch
    :class:`~spotlights.learning.inference.Completer` or an :class:`~spotlights.learning.export.OnnxCompleter`): ``complete(partials (B, K, 3) float32,
    unit frame) -> B arrays (K_i, 3) float32, unit frame``. Raises :class:`~spotlights.errors.ParameterError`
    for a runtime that does not fit the file, :class:`~spotlights.errors.InputFileError` for a bad file, and
    :class:`~spotlights.errors.SpotlightsError` when the runtime's package is not installed.
    """
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, numbers.Integral) or threads < 1):
        raise ParameterError(f"threads must be a whole number >= 1 or None (the runtime's default), got {threads!r}")
    if runtime is not None and runtime not in RUNTIMES:
        raise ParameterError(f"unknown runtime {runtime!r}; choose one of {', '.join(RUNTIMES)}")
    is_onnx = str(name_or_path or "").lower().endswith(".onnx")
    if runtime == "onnx" or (runtime is None and is_onnx):
        if name_or_path is None or not is_onnx:
            raise ParameterError(
                "`runtime` onnx runs an ONNX file: pass `checkpoint` MODEL.onnx "
                "(make one with 'spotlights export CHECKPOINT `out` MODEL.onnx')",
                "runtime",
                "checkpoint",
                "out",
            )
        if precision not in (None, "fp32"):
            raise ParameterError(
                "`precision` applies to the torch runtime; an ONNX model runs as exported (float32)", "precision"
            )
        return load_onnx_completer(name_or_path, threads=threads)
    if runtime == "torch" and is_onnx:
        raise ParameterError(f"{name_or_path} is an ONNX file: run it with `runtime` onnx", "runtime")
    return load_torch_completer(name_or_path, device=device, precision=precision or "fp32")


__all__ = ["RUNTIMES", "load_completer"]
