"""ONNX export of a trained model and a second runtime (onnxruntime) behind the ``Completer`` interface.

``export_onnx(checkpoint, out)`` writes one ONNX file per checkpoint (every registered model):

* **inputs**: ``partial`` (B, K, 3) float32 unit-frame points (B and K dynamic; the models were
  trained with K = 256); box-rig SA-Nets also take ``directions`` (B, N*M, 3) float32, each
  scan's ray directions (:func:`spotlights.learning.rays.directions_for_extents`);
* **outputs**: point models ``points`` (B, P, 3); SA-Nets ``depths`` (B, N*M) (the raw
  regression) and ``ray_points`` (B, N*M, 3), every ray decoded at its clamped depth
  (:meth:`SANet.ray_points`); the hit-aware SA-Net also ``hit_probability`` (B, N*M);
* **metadata** (``metadata_props``): ``spotlights_format`` = ``spotlights-onnx``,
  ``spotlights_format_version``, ``model_name``, ``rig`` (the RigSpec as JSON), ``needs_box``,
  ``clip`` and ``threshold`` (JSON; null when none), ``param_counts``, ``outputs``,
  ``input_points``, ``checkpoint`` and ``spotlights_version``.

Which rays a completion keeps is decided outside the graph, from those outputs, exactly as
the torch models decide it: SA-Net ``depth > 0`` and ``depth >= clip``; the hit-aware SA-Net
``p(hit) >= threshold`` (and ``depth >= clip`` when it has a clip). So ``--clip`` still works with
the ONNX runtime. :class:`OnnxCompleter` runs a file with onnxruntime (the optional extra
``spotlights[onnx]``) and has the :class:`~spotlights.learning.inference.Completer` interface
(``complete(partials, clip=..., extents=...)``, ``needs_box``, ``model_name``, ``rig``, ``clip``,
``threshold``), so ``complete_scan`` and ``spotlights complete --runtime onnx`` use it unchanged.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._version import __version__
from ..errors import InputFileError, ParameterError, SpotlightsError
from ..utils import atomic_output
from .checkpoint import load_checkpoint, model_from_checkpoint, resolve_checkpoint
from .inference import DEFAULT as TORCH_DEFAULT
from .inference import LearnedDomain
from .rays import TIMING_BOX_SIZE, directions_for_extents, extents_from_sizes, rig_spec, timing_directions

FORMAT = "spotlights-onnx"
FORMAT_VERSION = 1
OPSET = 18
INSTALL_HINT = "the ONNX runtime is an optional extra: pip install 'spotlights[onnx]' (onnx, onnxruntime)"


def _require(module: str):
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise SpotlightsError(f"{module} is not installed; {INSTALL_HINT}") from None


class _quiet:
    """Silence the exporter's progress prints, warnings and log lines (stdout, ``warnings``, ``logging``)."""

    def __enter__(self):
        import contextlib
        import io
        import logging
        import warnings

        self._stack = contextlib.ExitStack()
        self._stack.enter_context(contextlib.redirect_stdout(io.StringIO()))
        self._stack.enter_context(warnings.catch_warnings())
        warnings.simplefilter("ignore")
        self._level = logging.root.manager.disable
        logging.disable(logging.WARNING)
        return self

    def __exit__(self, *exc):
        import logging

        logging.disable(self._level)
        self._stack.close()
        return False


def _graph_module(model):
    """A torch module whose forward is the exported graph (see the module docstring)."""
    import torch

    class PointGraph(torch.nn.Module):
        def __init__(self, m):
            super().__init__()
            self.m = m

        def forward(self, partial):
            return self.m(partial)["points"]

    class DepthGraph(torch.nn.Module):
        def __init__(self, m):
            super().__init__()
            self.m = m
            self.hit = hasattr(m, "hit_probabilities")

        def outputs(self, partial, directions):
            out = self.m(partial)
            res = (out["depths"], self.m.ray_points(out["depths"], directions))
            if self.hit:
                res = (*res, torch.sigmoid(out["hit_logits"]))
            return res

    class CapGraph(DepthGraph):
        def forward(self, partial):
            return self.outputs(partial, None)

    class BoxGraph(DepthGraph):
        def forward(self, partial, directions):
            return self.outputs(partial, directions)

    if getattr(model, "uses_evidence", False):
        raise ParameterError(
            f"{model.name} cannot be exported to ONNX yet (its per-ray evidence is gathered with scatter "
            "reductions at run time); complete with the torch runtime"
        )
    if model.target == "points":
        return PointGraph(model), ["partial"], ["points"]
    names = ["depths", "ray_points"] + (["hit_probability"] if hasattr(model, "hit_probabilities") else [])
    if model.needs_box:
        return BoxGraph(model), ["partial", "directions"], names
    return CapGraph(model), ["partial"], names


def export_onnx(checkpoint, out, opset: int = OPSET, n_input: int = 256) -> Path:
    """Export a checkpoint (path or short name) to ONNX at ``out``; returns ``out``.

    The graph is checked with ``onnx.checker`` before the file is renamed into place (written to
    a temporary name first, nothing is left behind on failure). Raises :class:`SpotlightsError`
    with an install hint when onnx or its exporter is missing.
    """
    import torch

    onnx = _require("onnx")
    _require("onnxscript")  # torch's ONNX exporter
    path = resolve_checkpoint(checkpoint)
    ckpt = load_checkpoint(path)
    model = model_from_checkpoint(ckpt, torch.device("cpu"))
    graph, inputs, outputs = _graph_module(model)
    graph.eval()
    b = torch.export.Dim("batch", min=1, max=65536)
    k = torch.export.Dim("points", min=1, max=1 << 20)
    x = (torch.rand(2, n_input, 3, generator=torch.Generator().manual_seed(0)) * 2 - 1) * 0.57
    args, shapes = (x,), {"partial": {0: b, 1: k}}
    if model.target == "depths" and model.needs_box:
        args = (x, timing_directions(model, 2))
        shapes["directions"] = {0: b}
    meta = {
        "spotlights_format": FORMAT,
        "spotlights_format_version": str(FORMAT_VERSION),
        "model_name": ckpt["model_name"],
        "rig": json.dumps(model.rig.to_dict() if model.target == "depths" else None),
        "needs_box": json.dumps(bool(getattr(model, "needs_box", False))),
        "clip": json.dumps(getattr(model, "clip", None)),
        "threshold": json.dumps(getattr(model, "threshold", None)),
        "param_counts": json.dumps(model.param_counts()),
        "outputs": json.dumps(outputs),
        "inputs": json.dumps(inputs),
        "input_points": str(n_input),
        "checkpoint": str(path),
        "spotlights_version": __version__,
        "domain": json.dumps(ckpt.get("domain") if isinstance(ckpt.get("domain"), dict) else None),
    }
    with atomic_output(out) as tmp:
        with torch.no_grad(), _quiet():
            prog = torch.onnx.export(
                graph,
                args,
                input_names=inputs,
                output_names=outputs,
                dynamic_shapes=shapes,
                opset_version=opset,
                dynamo=True,
                external_data=False,
                verbose=False,
            )
        proto = prog.model_proto
        del proto.metadata_props[:]
        for key, value in meta.items():
            entry = proto.metadata_props.add()
            entry.key, entry.value = key, value
        onnx.checker.check_model(proto)
        onnx.save(proto, str(tmp))
    return Path(out)


class _Default:
    def __repr__(self):
        return "default"


DEFAULT = _Default()


class OnnxCompleter:
    """A ``spotlights export`` ONNX file run with onnxruntime, with the interface of
    :class:`~spotlights.learning.inference.Completer`.

    Attributes: ``model_name``, ``n_params``, ``param_counts``, ``rig`` (RigSpec or None),
    ``clip``, ``threshold``, ``needs_box``, ``path``, ``session`` (the onnxruntime session),
    ``device`` (``"onnxruntime:CPUExecutionProvider"`` or the first provider used).
    """

    def __init__(self, path, threads: int | None = None, providers=None):
        ort = _require("onnxruntime")
        onnx = _require("onnx")
        p = Path(path)
        if not p.is_file():
            raise InputFileError(p, "no such ONNX file")
        try:
            proto = onnx.load(str(p), load_external_data=False)
        except Exception as exc:  # noqa: BLE001 - any parse failure is a bad file
            raise InputFileError(p, f"not a readable ONNX file ({str(exc).splitlines()[0][:100]})") from None
        meta = {m.key: m.value for m in proto.metadata_props}
        if meta.get("spotlights_format") != FORMAT:
            raise InputFileError(
                p,
                "not a spotlights ONNX export (no spotlights_format metadata; make one with "
                "'spotlights export CHECKPOINT --out model.onnx')",
            )
        if int(meta.get("spotlights_format_version", 0)) > FORMAT_VERSION:
            raise InputFileError(
                p,
                f"ONNX export format {meta.get('spotlights_format_version')} is newer than this "
                f"spotlights ({FORMAT_VERSION})",
            )
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = int(threads)
        self.session = ort.InferenceSession(str(p), opts, providers=providers or ["CPUExecutionProvider"])
        self.path = p
        self.meta = meta
        self.model_name = meta["model_name"]
        self.param_counts = json.loads(meta["param_counts"])
        self.n_params = int(self.param_counts["total"])
        rig = json.loads(meta.get("rig", "null"))
        if rig is not None:
            rig = rig_spec(rig)
        self.rig = rig
        self.needs_box = bool(json.loads(meta.get("needs_box", "false")))
        self.clip = json.loads(meta.get("clip", "null"))
        self.threshold = json.loads(meta.get("threshold", "null"))

        self.domain = LearnedDomain.from_checkpoint({"domain": json.loads(meta.get("domain", "null"))})
        self.outputs = json.loads(meta["outputs"])
        self.inputs = json.loads(meta["inputs"])
        self.device = f"onnxruntime:{self.session.get_providers()[0]}"

    def __repr__(self):
        return f"OnnxCompleter({self.model_name}, {self.n_params:,} parameters, {self.path})"

    def run(self, partials: np.ndarray, directions: np.ndarray | None = None) -> dict:
        """Raw graph outputs {name: array} of (B, K, 3) float32 partials (and (B, N*M, 3) directions for box rigs)."""
        feed = {"partial": np.ascontiguousarray(partials, dtype=np.float32)}
        if "directions" in self.inputs:
            feed["directions"] = np.ascontiguousarray(directions, dtype=np.float32)
        return dict(zip(self.outputs, self.session.run(self.outputs, feed)))

    def keep(self, out: dict, clip=DEFAULT) -> np.ndarray:
        """(B, N*M) bool rays a completion keeps (the torch models' rule; see the module docstring)."""
        c = self.clip if clip is DEFAULT else clip
        depths = out["depths"]
        mask = out["hit_probability"] >= np.float32(self.threshold) if "hit_probability" in out else depths > 0
        if c is not None:
            mask &= depths >= np.float32(c)
        return mask

    def complete(self, partials: np.ndarray, clip=DEFAULT, batch_size: int = 256, extents=None) -> list[np.ndarray]:
        """Complete partial scans, as :meth:`Completer.complete` (same arguments, same results up to float rounding)."""
        x = np.asarray(partials, dtype=np.float32)
        if x.ndim == 2:
            x = x[None]
        if x.ndim != 3 or x.shape[-1] != 3:
            raise ParameterError(f"partials must have shape (B, K, 3), got {x.shape}")
        if x.shape[0] == 0:
            return []
        if x.shape[1] == 0:
            raise ParameterError("partial scans are empty (K = 0 points)")
        if not np.all(np.isfinite(x)):
            raise ParameterError("partial scans contain NaN or infinite coordinates")
        clip = DEFAULT if clip is TORCH_DEFAULT else clip
        e = None
        if self.needs_box:
            if extents is None:
                raise ParameterError(
                    f"this SA-Net regresses the box-targeted rig {self.rig.name}: give each scan's box "
                    "half-extents (extents = size / |size|)"
                )
            e = np.asarray(extents, dtype=np.float64)
            e = np.broadcast_to(e, (len(x), 3)) if e.shape == (3,) else e
            if e.shape != (len(x), 3):
                raise ParameterError(f"extents must have shape ({len(x)}, 3) or (3,), got {np.shape(extents)}")
        result: list[np.ndarray] = []
        for s in range(0, len(x), batch_size):
            dirs = None
            if e is not None:
                dirs = directions_for_extents(self.rig, e[s : s + batch_size])
            out = self.run(x[s : s + batch_size], dirs)
            if "points" in out:
                result.extend(np.ascontiguousarray(p, dtype=np.float32) for p in out["points"])
                continue
            mask = self.keep(out, clip)
            result.extend(p[m].astype(np.float32) for p, m in zip(out["ray_points"], mask))
        return result


def load_onnx_completer(path, threads: int | None = None) -> OnnxCompleter:
    """An :class:`OnnxCompleter` for a ``spotlights export`` file (one-line errors; install hint without onnxruntime)."""
    return OnnxCompleter(path, threads=threads)


def parity(checkpoint, onnx_completer: OnnxCompleter, partials: np.ndarray | None = None, extents=None) -> dict:
    """Largest absolute difference of every graph output, onnxruntime against the torch model of ``checkpoint``
    (float32, CPU), on ``partials`` (default: 8 seeded random clouds; box rigs: a car's box, or ``extents``).

    Returns {output name: max |onnx - torch|}, plus ``kept_rays_differ``: rays kept by one and not the other.
    """
    import torch

    model = model_from_checkpoint(load_checkpoint(resolve_checkpoint(checkpoint)), torch.device("cpu"))
    x = partials if partials is not None else (np.random.default_rng(0).normal(size=(8, 256, 3)) * 0.3)
    x = np.ascontiguousarray(x, dtype=np.float32)
    dirs = None
    if getattr(model, "needs_box", False):
        e = extents if extents is not None else extents_from_sizes(TIMING_BOX_SIZE)
        e = np.broadcast_to(np.asarray(e, dtype=np.float64), (len(x), 3))
        dirs = directions_for_extents(model.rig, e)
    graph, _, names = _graph_module(model)
    with torch.inference_mode():
        args = (torch.from_numpy(x),) + ((torch.from_numpy(np.ascontiguousarray(dirs)),) if dirs is not None else ())
        ref = graph(*args)
    ref = ref if isinstance(ref, tuple) else (ref,)
    ref = {n: t.numpy() for n, t in zip(names, ref)}
    got = onnx_completer.run(x, dirs)
    out = {n: float(np.abs(got[n] - ref[n]).max()) for n in names}
    if "depths" in ref:
        keep_ref = onnx_completer.keep(ref)
        out["kept_rays_differ"] = int((onnx_completer.keep(got) != keep_ref).sum())
    return out
