"""The runtime choice: a completer from a checkpoint name or file, run with torch or with onnxruntime.

:func:`load_completer` is the one place that decides which runtime runs a model (``spotlights complete``,
``real complete`` and the public :func:`spotlights.load_completer` call it):

* ``"auto"`` (the default): onnxruntime on the CPU for a packaged model shipped with its ONNX export
  (``default``, ``classes``: ``learning/pretrained/NAME.onnx``) when onnxruntime imports, and for any ``.onnx``
  file; torch for every other checkpoint, on a CUDA device (one given, or an NVIDIA driver present and no device
  given), or for ``precision="bf16"``. A one-frame completion then never imports torch (its start-up was 95% of
  ``spotlights complete`` on one frame); the exports give torch's outputs within float rounding
  (docs/studies/speed.md: parity). A run of :data:`MANY_FRAMES` frames or more (``frames``: ``real complete``)
  on a CPU that multiplies bfloat16 natively runs torch at bf16 instead when torch is installed: there its scans
  cost less CPU than onnxruntime's float32 ones (2.44 against 3.62 ms a scan, one thread, batch 32) and the
  frames repay torch's start-up (nuScenes scene-0523, 40 frames, ``--fuse past:5 --refine-boxes``: 14.4 frames/s
  against 8.5, docs/studies/speed.md);
* ``"onnx"``: an ONNX file, or the shipped export of a packaged name;
* ``"torch"``: a checkpoint with torch (:class:`~spotlights.learning.inference.Completer`).

``precision="auto"`` (the default) is float32 with onnxruntime and bfloat16 autocast with torch on a CPU that
multiplies bfloat16 natively (:func:`spotlights.learning.cpu.auto_precision`). Every completer says what ran:
``runtime`` (``"torch"`` or ``"onnx"``) and ``precision`` (``"fp32"``, ``"bf16"``, ``"fp16"``). Neither runtime
is imported before it is needed.
"""

from __future__ import annotations

import numbers
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Literal

from ..errors import ParameterError
from .checkpoint import PRETRAINED
from .cpu import auto_precision, has_bf16
from .export import load_onnx_completer
from .inference import BaseCompleter
from .inference import load_completer as load_torch_completer

RUNTIMES = ("auto", "torch", "onnx")

Runtime = Literal["auto", "torch", "onnx"]

PRECISIONS = ("auto", "fp32", "bf16")

MANY_FRAMES = 8
"""From this many frames on, ``"auto"`` prefers torch at bf16 on a CPU with native bfloat16 (module docstring)."""

PRETRAINED_DIR = Path(__file__).resolve().parent / "pretrained"


def shipped_onnx(name: str | os.PathLike | None) -> Path | None:
    """The ONNX export shipped beside a packaged model (``pretrained/NAME.onnx`` of a short name; None =
    ``"default"``), or None (not a short name, or no export shipped)."""
    key = "default" if name is None else os.fspath(name)
    if key not in PRETRAINED:
        return None
    p = PRETRAINED_DIR / f"{Path(PRETRAINED[key]).stem}.onnx"
    return p if p.is_file() else None


def onnxruntime_imports() -> bool:
    """Whether onnxruntime (the optional extra ``spotlights[onnx]``) can be imported here."""
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


def cuda_present() -> bool:
    """Whether this machine may have a CUDA device, read without torch: an NVIDIA driver is loaded and
    ``CUDA_VISIBLE_DEVICES`` does not hide every device."""
    if os.environ.get("CUDA_VISIBLE_DEVICES", None) in ("", "-1"):
        return False
    return os.path.exists("/proc/driver/nvidia/version") or os.path.exists("/dev/nvidiactl")


def choose_runtime(
    name_or_path: str | os.PathLike | None = "default",
    runtime: str | None = "auto",
    device: str | None = None,
    precision: str | None = "auto",
    frames: int = 1,
    flags: Iterable[str] | None = None,
) -> tuple[str, str | os.PathLike | None]:
    """The runtime a model runs with and what it loads: ``("onnx", ONNX file)`` or ``("torch", checkpoint)``.

    The rules of :func:`load_completer` (see the module docstring); ``runtime`` None is ``"auto"``; ``frames``: how
    many frames the model will complete (a hint for ``"auto"``); ``flags``: the CPU's flags (default: this CPU's,
    :func:`spotlights.learning.cpu.cpu_flags`). Raises
    :class:`ParameterError` for an unknown runtime or precision, or one that does not fit the model.
    """
    runtime = "auto" if runtime is None else runtime
    _check_choices(runtime, precision)
    is_onnx = str(name_or_path or "").lower().endswith(".onnx")
    if runtime == "torch":
        if is_onnx:
            raise ParameterError(f"{name_or_path} is an ONNX file: run it with `runtime` onnx", "runtime")
        return "torch", name_or_path
    if is_onnx:
        return "onnx", name_or_path
    shipped = shipped_onnx(name_or_path)
    if runtime == "onnx":
        return "onnx", _required_export(shipped)
    return _auto_runtime(name_or_path, shipped, device, precision, frames, flags)


def _check_choices(runtime: str, precision: str | None) -> None:
    """Refuse an unknown ``runtime`` or ``precision``."""
    if runtime not in RUNTIMES:
        raise ParameterError(f"unknown `runtime` {runtime!r}; choose one of {', '.join(RUNTIMES)}", "runtime")
    if precision is not None and precision not in PRECISIONS:
        raise ParameterError(f"unknown `precision` {precision!r}; choose one of {', '.join(PRECISIONS)}", "precision")


def _required_export(shipped: Path | None) -> Path:
    """``shipped`` (the ONNX export of a packaged model) for ``runtime="onnx"``; a :class:`ParameterError` saying
    how to make one when the model has none."""
    if shipped is None:
        raise ParameterError(
            "`runtime` onnx runs an ONNX file: pass `checkpoint` MODEL.onnx "
            "(make one with 'spotlights export CHECKPOINT `out` MODEL.onnx'; the packaged "
            f"{', '.join(n for n in PRETRAINED if shipped_onnx(n) is not None)} ship one)",
            "runtime",
            "checkpoint",
            "out",
        )
    return shipped


def _auto_runtime(
    name_or_path: str | os.PathLike | None,
    shipped: Path | None,
    device: str | None,
    precision: str | None,
    frames: int,
    flags: Iterable[str] | None,
) -> tuple[str, str | os.PathLike | None]:
    """``runtime="auto"`` for a checkpoint (not an ONNX file; ``shipped``: its packaged export, or None): the export
    with onnxruntime on the CPU, unless bf16 is asked or many frames on a CPU with native bfloat16 repay torch."""
    on_cpu = str(device).split(":")[0] == "cpu" if device is not None else not cuda_present()
    if shipped is not None and on_cpu and precision != "bf16" and onnxruntime_imports():
        many = frames >= MANY_FRAMES and precision in (None, "auto") and has_bf16(flags) and torch_imports()
        return ("torch", name_or_path) if many else ("onnx", shipped)
    return "torch", name_or_path


def torch_imports() -> bool:
    """Whether torch is installed (found, not imported: the check costs no start-up)."""
    import importlib.util

    return importlib.util.find_spec("torch") is not None


def load_completer(
    name_or_path: str | os.PathLike | None = "default",
    runtime: Runtime | None = "auto",
    device: str | None = None,
    precision: str | None = "auto",
    threads: int | None = None,
    frames: int = 1,
) -> BaseCompleter:
    """A completion model ready for inference.

    Parameters
    ----------
    name_or_path : a checkpoint file (``.pt``), a short name (``"default"``: the package's default model;
        ``"paper"``: the paper-faithful SA-Net; ``"classes"``: the class model; None = ``"default"``) or a
        ``spotlights export`` ``.onnx`` file.
    runtime : ``"auto"`` (default; None is the same), ``"torch"`` or ``"onnx"`` (:func:`choose_runtime`, the
        module docstring).
    device : torch device or name (torch runtime; default CUDA when available, else CPU); ``"cpu"`` (or None on a
        machine without an NVIDIA driver) lets ``"auto"`` choose onnxruntime.
    precision : ``"auto"`` (default: :func:`spotlights.learning.cpu.auto_precision`), ``"fp32"`` or ``"bf16"``
        (torch autocast; an ONNX model runs as exported, float32, and refuses ``"bf16"``).
    threads : onnx runtime: onnxruntime's intra-op threads, >= 1 (None: its default); the torch runtime's threads are the
        process's (``torch.set_num_threads``).
    frames : how many frames the model will complete (``"auto"`` prefers torch at bf16 from :data:`MANY_FRAMES` on,
        on a CPU with native bfloat16).

    Returns a :class:`~spotlights.learning.inference.BaseCompleter` (a torch
    :class:`~spotlights.learning.inference.Completer` or an :class:`~spotlights.learning.export.OnnxCompleter`): ``complete(partials (B, K, 3) float32,
    unit frame) -> B arrays (K_i, 3) float32, unit frame``; its ``runtime`` and ``precision`` say what runs.
    Raises :class:`~spotlights.errors.ParameterError` for a runtime that does not fit the file,
    :class:`~spotlights.errors.InputFileError` for a bad file, and :class:`~spotlights.errors.SpotlightsError`
    when the runtime's package is not installed.
    """
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, numbers.Integral) or threads < 1):
        raise ParameterError(
            f"`threads` must be a whole number >= 1 or None (the runtime's default), got {threads!r}", "threads"
        )
    chosen, what = choose_runtime(name_or_path, runtime, device, precision, frames)
    if chosen == "onnx":
        if precision not in (None, "auto", "fp32"):
            raise ParameterError(
                "`precision` applies to the torch runtime; an ONNX model runs as exported (float32)", "precision"
            )
        return load_onnx_completer(what, threads=threads)
    if precision in (None, "auto"):
        device_type = "cpu" if device is None and not cuda_present() else str(device or "cuda").split(":")[0]
        precision = auto_precision("torch", device_type)
    return load_torch_completer(what, device=device, precision=precision)


def runs_with(completer: object) -> str:
    """What runs a completer, as summary lines say it: ``"onnxruntime fp32"``, ``"torch bf16"``..."""
    runtime = getattr(completer, "runtime", "torch")
    name = "onnxruntime" if runtime == "onnx" else str(runtime)
    return f"{name} {getattr(completer, 'precision', 'fp32')}"


def fallback_runtime(main_runtime: str | None, fallback: str | os.PathLike | None) -> Runtime:
    """The runtime of the fallback model beside a main model run with ``main_runtime`` (as asked: ``auto``,
    ``torch``, ``onnx``): the same, except where the fallback cannot run with it (an ``.onnx`` fallback beside
    torch; a checkpoint without an export beside onnx): then ``"auto"``, its file decides."""
    asked: Runtime = "torch" if main_runtime == "torch" else "onnx" if main_runtime == "onnx" else "auto"
    is_onnx = str(fallback or "").lower().endswith(".onnx")
    if asked == "torch" and is_onnx:
        return "auto"
    if asked == "onnx" and not is_onnx and shipped_onnx(fallback) is None:
        return "auto"
    return asked


__all__ = [
    "PRECISIONS",
    "RUNTIMES",
    "choose_runtime",
    "cuda_present",
    "fallback_runtime",
    "load_completer",
    "onnxruntime_imports",
    "runs_with",
    "shipped_onnx",
]
