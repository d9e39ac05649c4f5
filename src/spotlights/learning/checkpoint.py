"""Checkpoint files: saving (atomic), loading with clear errors, rebuilding the model.

A checkpoint is a ``torch.save`` dict (loadable with ``weights_only=True``)::

    format            "spotlights-checkpoint"      format_version  1
    spotlights_version
    model_name        registry key, e.g. "sanet"
    config            the full resolved config (model / data / train)
    rig               Rig.to_dict() of the depths' rig (SA-Net), else None
    model_state       the model's state_dict
    param_counts      {"encoder", "decoder", "total"}
    epoch             number of completed epochs;  global_step
    optimizer_state, scheduler_state   (training checkpoints; absent in exported weights)
    best              {"epoch", "val_accuracy"};  history  list of per-epoch log rows
    hit_threshold     hit-aware SA-Net only: {"value": p(hit) threshold chosen on the validation
                      split, "chosen_on", "criterion", "scan": {threshold: val metrics}}
    dataset           {"path", "rig", "n_train", "n_val"} (informative)
"""

from __future__ import annotations

import io
import os
from pathlib import Path

from .._version import __version__
from ..errors import InputFileError
from ..outputs import atomic_output
from .models import MODEL_REGISTRY, build_model

FORMAT = "spotlights-checkpoint"
FORMAT_VERSION = 1

#: Short checkpoint names -> files shipped in ``spotlights/learning/pretrained/``.
#: ``default`` is the model every command uses when ``--checkpoint`` is not given: the product
#: model, the hit-aware SA-Net on the dense box-targeted rig (16,384 rays, no clip); ``paper`` is
#: the paper-faithful SA-Net (32 x 64 rays at 60 degrees, clip 0.2).
#: ``scripts/ship_pretrained.py`` writes a file (float16 weights) and checks it.
PRETRAINED: dict[str, str] = {"default": "default.pt", "paper": "paper.pt", "classes": "classes.pt"}


def resolve_checkpoint(name=None) -> Path:
    """The checkpoint file behind a ``--checkpoint`` value.

    ``None`` or ``"default"``: the package's default model; a short name of :data:`PRETRAINED`
    (``"paper"``): its shipped file; anything else: a path (``~`` expanded). A path that
    happens to equal a short name is taken as the short name unless it contains a separator
    or a suffix (``./default`` or ``default.pt`` are files).

    Raises :class:`InputFileError` for a missing file (naming the short names, so a typo
    in a name is caught) or a short name whose file this installation does not ship.
    """
    from importlib import resources

    key = "default" if name is None else os.fspath(name)
    if key in PRETRAINED:
        p = Path(str(resources.files("spotlights.learning") / "pretrained" / PRETRAINED[key]))
        if not p.is_file():
            raise InputFileError(
                p,
                f"the '{key}' checkpoint is not shipped in this installation; pass a checkpoint "
                "file (train one with 'spotlights train --model sanet --data DATASET.h5')",
            )
        return p
    p = Path(key).expanduser()
    if not p.exists():
        raise InputFileError(p, f"no such checkpoint file (short names: {', '.join(PRETRAINED)})")
    return p


def save_checkpoint(path, payload: dict) -> Path:
    """Write ``payload`` (plus format fields) to ``path`` atomically (temporary file, then rename)."""
    import torch

    data = {"format": FORMAT, "format_version": FORMAT_VERSION, "spotlights_version": __version__, **payload}
    buf = io.BytesIO()  # serialised in memory first: torch's file writer turns a full disk into a
    torch.save(data, buf)  # RuntimeError ("unexpected pos"); a plain write raises OSError, one clean line
    with atomic_output(path) as tmp:
        tmp.write_bytes(buf.getbuffer())
    return Path(path)


def load_checkpoint(path, expect_model: str | None = None, map_location="cpu") -> dict:
    """Read and validate a checkpoint.

    Parameters
    ----------
    path : checkpoint file, or a short name of :data:`PRETRAINED` (``default``, ``paper``).
    expect_model : if given, the registry name the checkpoint must hold (e.g. ``"sanet"``).

    Raises
    ------
    InputFileError : missing file, not a torch file, not a spotlights checkpoint,
        unknown model, or a model other than ``expect_model``.
    """
    import torch

    p = resolve_checkpoint(path)
    if p.is_dir():
        raise InputFileError(p, "is a folder, expected a checkpoint file (e.g. RUN/best.pt)")
    if p.suffix.lower() == ".onnx":
        raise InputFileError(
            p,
            "is an ONNX model: this command reads PyTorch checkpoints (.pt); ONNX models run in 'complete' and "
            "'real complete' (--runtime onnx)",
        )
    ckpt = _read_torch_file(torch, p, map_location)
    _check_format(p, ckpt)
    name = ckpt.get("model_name")
    if not isinstance(name, str) or name not in MODEL_REGISTRY:
        raise InputFileError(p, f"checkpoint holds an unknown model {name!r}")
    if expect_model is not None and name != expect_model:
        raise InputFileError(p, f"checkpoint holds a {name!r} model, expected {expect_model!r}")
    _check_entries(torch, p, ckpt)
    ckpt["path"] = os.fspath(p)
    return ckpt


def _read_torch_file(torch, p: Path, map_location):
    """The object of the torch file ``p`` (weights only; ``torch`` the module); a one-line :class:`InputFileError`
    for a file that is not one (truncated, garbage)."""
    try:
        return torch.load(p, map_location=map_location, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any failure of unpickling garbage is the file's fault
        msg = (str(exc).splitlines() or [""])[0]
        cut = isinstance(exc, EOFError) or "central directory" in msg  # the zip's index is at the file's end
        msg = msg.split(". This is an internal")[0][:100]  # torch's own advice is not for the user
        what = "truncated (its end is missing)" if cut else "not a readable checkpoint"
        raise InputFileError(p, f"{what} ({type(exc).__name__}: {msg})" if msg else what) from None


def _check_format(p: Path, ckpt) -> None:
    """Refuse what is not a spotlights checkpoint of a format version this installation reads."""
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise InputFileError(p, "not a spotlights checkpoint (no 'format: spotlights-checkpoint' entry)")
    if not isinstance(ckpt.get("format_version", 0), int):
        raise InputFileError(p, "damaged checkpoint: its 'format_version' entry is not an integer")
    if ckpt.get("format_version", 0) > FORMAT_VERSION:
        raise InputFileError(
            p,
            f"checkpoint format version {ckpt.get('format_version')} is newer than this spotlights ({FORMAT_VERSION})",
        )


def _check_entries(torch, p: Path, ckpt: dict) -> None:
    """Refuse a checkpoint whose ``config`` is not a model/data/train mapping or whose ``model_state`` is not a
    mapping of tensors (``torch`` the module)."""
    for key in ("config", "model_state"):
        if key not in ckpt:
            raise InputFileError(p, f"checkpoint lacks its {key!r} entry")
    cfg = ckpt["config"]
    if not isinstance(cfg, dict) or not all(isinstance(cfg.get(k, {}), dict) for k in ("model", "data", "train")):
        raise InputFileError(p, "damaged checkpoint: its 'config' entry is not a model/data/train mapping")
    if not isinstance(ckpt["model_state"], dict) or not all(
        isinstance(v, torch.Tensor) for v in ckpt["model_state"].values()
    ):
        raise InputFileError(p, "damaged checkpoint: its 'model_state' entry is not a mapping of tensors")


def model_from_checkpoint(ckpt: dict, device=None):
    """Rebuild the model of a loaded checkpoint, load its weights, move it to ``device``, eval mode.

    Raises :class:`InputFileError` when the weights do not fit the model the config describes.
    """
    import torch

    try:
        model = build_model(ckpt["config"], rig=ckpt.get("rig"))
        model.load_state_dict(ckpt["model_state"])
        chosen = ckpt.get("hit_threshold")
        if chosen is not None and hasattr(model, "threshold"):  # hit-aware SA-Net: the p(hit) threshold chosen on val
            model.threshold = float(chosen["value"] if isinstance(chosen, dict) else chosen)
    except Exception as exc:  # noqa: BLE001 - any config or weights that do not build are the file's fault
        first = (str(exc).splitlines() or [type(exc).__name__])[0][:160]
        raise InputFileError(
            ckpt.get("path", "checkpoint"), f"weights do not match the {ckpt['model_name']} config ({first})"
        ) from None
    bad = [
        name for name, t in model.state_dict().items() if t.is_floating_point() and not bool(torch.isfinite(t).all())
    ]
    if bad:  # a run that diverged: every completion would be NaN (export's parity and evaluate's scores passed)
        raise InputFileError(
            ckpt.get("path", "checkpoint"),
            f"weights hold NaN or infinite values ({bad[0]}{f' and {len(bad) - 1} more' if len(bad) > 1 else ''})",
        )
    threshold = getattr(model, "threshold", None)
    if threshold is not None:
        from .models.sanet_hit import check_probability  # loaded already: the model was built from it

        try:
            check_probability(threshold, "its p(hit) threshold")
        except ValueError as exc:
            raise InputFileError(ckpt.get("path", "checkpoint"), str(exc)) from None
    model = model.float()
    if device is not None:
        model = model.to(torch.device(device))
    return model.eval()


def export_weights(src, dst, half: bool = False) -> Path:
    """Write an inference-only copy of a checkpoint (no optimizer/scheduler state).

    ``half=True`` stores floating-point weights as float16 (half the size; they are
    cast back to float32 on load). Returns ``dst``.
    """
    import torch

    ckpt = load_checkpoint(src)
    keep = {
        k: v
        for k, v in ckpt.items()
        if k
        not in (
            "optimizer_state",
            "scheduler_state",
            "scaler_state",
            "path",
            "format",
            "format_version",
            "spotlights_version",
        )
    }
    if half:
        keep["model_state"] = {
            k: (v.half() if torch.is_floating_point(v) else v) for k, v in ckpt["model_state"].items()
        }
    return save_checkpoint(dst, keep)
