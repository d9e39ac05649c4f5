"""ONNX export of a trained model and a second runtime (onnxruntime) behind the ``Completer`` interface.

``export_onnx(checkpoint, out)`` writes one ONNX file per checkpoint (every registered model):

* **inputs**: ``partial`` (B, K, 3) float32 unit-frame points (B and K dynamic; the models were
  trained with K = 256); box-rig SA-Nets also take ``directions`` (B, N*M, 3) float32, each
  scan's ray directions (:func:`spotlights.learning.rays.directions_for_extents`); class-conditioned
  SA-Nets (a ``classes`` vocabulary) also take ``classes`` (B,) int64, each scan's row of the vocabulary
  (-1: no class, the code as the encoder gives it), the last input;
* **outputs**: point models ``points`` (B, P, 3); SA-Nets ``depths`` (B, N*M) (the raw
  regression) and ``ray_points`` (B, N*M, 3), every ray decoded at its clamped depth
  (:meth:`SANet.ray_points`); the hit-aware SA-Net also ``hit_probability`` (B, N*M);
* **metadata** (``metadata_props``): ``spotlights_format`` = ``spotlights-onnx``,
  ``spotlights_format_version``, ``model_name``, ``rig`` (the RigSpec as JSON), ``needs_box``,
  ``clip`` and ``threshold`` (JSON; null when none), ``param_counts``, ``outputs``, ``inputs``,
  ``input_points``, ``checkpoint``, ``spotlights_version``, ``domain`` (the checkpoint's learned domain:
  classes and per-class size ranges) and, for a class-conditioned model only, ``classes`` (its vocabulary in
  embedding-row order, JSON). A file with a class input is format version 2 (a reader of version 1 refuses
  it in one line instead of failing to feed it); every other export is still version 1, byte for byte.

Which rays a completion keeps is decided outside the graph, from those outputs, exactly as
the torch models decide it: SA-Net ``depth > 0`` and ``depth >= clip``; the hit-aware SA-Net
``p(hit) >= threshold`` (and ``depth >= clip`` when it has a clip). So ``--clip`` still works with
the ONNX runtime. :class:`OnnxCompleter` (:mod:`spotlights.learning.onnx_runtime`, re-exported here) runs a
file with onnxruntime (the optional extra ``spotlights[onnx]``) and has the :class:`~spotlights.learning.inference.Completer` interface
(``complete(partials, clip=..., extents=..., classes=..., box_half=...)``, ``needs_box``, ``model_name``,
``rig``, ``clip``, ``threshold``, ``classes``, ``domain``), so ``complete_scan``, ``complete_frame`` (the
learned-domain gate, ``--fallback``) and ``spotlights complete --runtime onnx`` use it unchanged: class names
become vocabulary rows as the torch ``Completer`` makes them
(:func:`spotlights.data.vehicle_classes.class_rows`).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .. import logs
from .._version import __version__
from ..errors import ParameterError
from ..geometry.boxes import unit_extents
from ..outputs import atomic_output
from .checkpoint import load_checkpoint, model_from_checkpoint, resolve_checkpoint
from .onnx_runtime import FORMAT, FORMAT_VERSION, OnnxCompleter, _require, load_onnx_completer

# the ONNX runtime lives in .onnx_runtime; its names stay importable from here
from .onnx_runtime import INSTALL_HINT as INSTALL_HINT
from .onnx_runtime import clip_rays_to_boxes as clip_rays_to_boxes
from .onnx_runtime import ray_points as ray_points
from .rays import TIMING_BOX_SIZE, directions_for_extents, timing_directions

BASE_FORMAT_VERSION = 1
"""The format of an export without a class input (unchanged since version 1)."""
OPSET = 18
# The lowest opset torch's exporter converts its graphs to (it writes 18 and converts; below 15 it
# kept 18 without a word, measured with torch 2.13 / onnxscript); the highest is the newest the
# installed onnx knows.
MIN_OPSET = 15


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

        def outputs(self, partial, directions, classes=None):
            out = self.m(partial) if classes is None else self.m(partial, classes)
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

    class ClassCapGraph(DepthGraph):
        def forward(self, partial, classes):
            return self.outputs(partial, None, classes)

    class ClassBoxGraph(DepthGraph):
        def forward(self, partial, directions, classes):
            return self.outputs(partial, directions, classes)

    if getattr(model, "uses_evidence", False):
        raise ParameterError(
            f"{model.name} cannot be exported to ONNX yet (its per-ray evidence is gathered with scatter "
            "reductions at run time); complete with the torch runtime"
        )
    if model.target == "points":
        return PointGraph(model), ["partial"], ["points"]
    names = ["depths", "ray_points"] + (["hit_probability"] if hasattr(model, "hit_probabilities") else [])
    if getattr(model, "class_embedding", None) is not None:
        if model.needs_box:
            return ClassBoxGraph(model), ["partial", "directions", "classes"], names
        return ClassCapGraph(model), ["partial", "classes"], names
    if model.needs_box:
        return BoxGraph(model), ["partial", "directions"], names
    return CapGraph(model), ["partial"], names


def _check_opset(onnx, opset: int) -> None:
    """Raise :class:`ParameterError` unless ``opset`` is one of :data:`MIN_OPSET` to the newest the installed onnx knows."""
    newest = int(onnx.defs.onnx_opset_version())
    if not MIN_OPSET <= int(opset) <= newest:
        raise ParameterError(
            f"`opset` {opset}: ONNX opsets {MIN_OPSET} to {newest} can be written (default {OPSET})", "opset"
        )


def _example_inputs(model, n_input: int) -> tuple[tuple, dict, list | None]:
    """The traced inputs of the export (a batch of 2 seeded random partials of ``n_input`` points, the box rig's
    directions, class rows), their dynamic shapes, and the class vocabulary (None without a class input)."""
    import torch

    b = torch.export.Dim("batch", min=1, max=65536)
    k = torch.export.Dim("points", min=1, max=1 << 20)
    x = (torch.rand(2, n_input, 3, generator=torch.Generator().manual_seed(0)) * 2 - 1) * 0.57
    args, shapes = (x,), {"partial": {0: b, 1: k}}
    if model.target == "depths" and model.needs_box:
        args = (x, timing_directions(model, 2))
        shapes["directions"] = {0: b}
    vocab = list(model.classes) if getattr(model, "class_embedding", None) is not None else None
    if vocab is not None:  # a class row and "no class" (-1): both paths of SANet.encode are traced
        args, shapes["classes"] = (*args, torch.tensor([0, -1], dtype=torch.int64)), {0: b}
    return args, shapes, vocab


def _metadata(ckpt: dict, model, path: Path, inputs: list, outputs: list, n_input: int, vocab) -> dict[str, str]:
    """The export's ``metadata_props`` (see the module docstring), as strings."""
    meta = {
        "spotlights_format": FORMAT,
        "spotlights_format_version": str(BASE_FORMAT_VERSION if vocab is None else FORMAT_VERSION),
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
    if vocab is not None:
        meta["classes"] = json.dumps(vocab)
    return meta


def _finish_proto(proto, opset: int, meta: dict[str, str]) -> None:
    """Check that the exporter wrote ``opset`` (else :class:`ParameterError`), then strip the per-node notes and
    set the metadata, in place."""
    written = {o.version for o in proto.opset_import if o.domain in ("", "ai.onnx")}
    if written != {int(opset)}:  # the exporter could not convert the graph and kept its own opset
        raise ParameterError(
            f"`opset` {opset}: the exporter cannot write this model at opset {opset} "
            f"(it wrote {', '.join(map(str, sorted(written)))}); try {OPSET} or higher",
            "opset",
        )
    strip_node_metadata(proto)
    del proto.metadata_props[:]
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value


def export_onnx(checkpoint, out, opset: int = OPSET, n_input: int = 256) -> Path:
    """Export a checkpoint (path or short name) to ONNX at ``out``; returns ``out``.

    The graph is checked with ``onnx.checker`` before the file is renamed into place (written to
    a temporary name first, nothing is left behind on failure). A class-conditioned SA-Net gets a
    ``classes`` (B,) int64 input and its vocabulary in the ``classes`` metadata (see the module docstring). ``opset`` must be one of
    :data:`MIN_OPSET` to the newest the installed onnx knows, and the graph must really be
    written at it (else :class:`ParameterError`, one line). Raises :class:`SpotlightsError`
    with an install hint when onnx or its exporter is missing.
    """
    import torch

    onnx = _require("onnx")
    _require("onnxscript")  # torch's ONNX exporter
    _check_opset(onnx, opset)
    path = resolve_checkpoint(checkpoint)
    ckpt = load_checkpoint(path)
    model = model_from_checkpoint(ckpt, torch.device("cpu"))
    graph, inputs, outputs = _graph_module(model)
    graph.eval()
    args, shapes, vocab = _example_inputs(model, n_input)
    meta = _metadata(ckpt, model, path, inputs, outputs, n_input, vocab)
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
        _finish_proto(proto, opset, meta)
        onnx.checker.check_model(proto)
        onnx.save(proto, str(tmp))
    return Path(out)


def halve_weights(proto, min_size: int = 1024) -> int:
    """Store ``proto``'s (an ``onnx.ModelProto``) float32 weights as float16, in place, where that loses nothing.

    Every float32 initializer of at least ``min_size`` values that float16 holds exactly (the shipped checkpoints'
    weights are float16 numbers: ``export_weights(half=True)``) is replaced by a float16 initializer and a ``Cast``
    node back to float32 at the head of the graph, so the graph computes with the same float32 weights (onnxruntime
    folds the casts when it loads the model) from a file about half the size. Returns the number of initializers
    halved."""
    from onnx import TensorProto, helper, numpy_helper

    graph, casts, n = proto.graph, [], 0
    for init in list(graph.initializer):
        if init.data_type != TensorProto.FLOAT:
            continue
        w = numpy_helper.to_array(init)
        if w.size < min_size:
            continue
        half = w.astype(np.float16)
        if not np.array_equal(half.astype(np.float32), w):
            continue
        name = init.name
        init.CopyFrom(numpy_helper.from_array(half, f"{name}__float16"))
        casts.append(helper.make_node("Cast", [f"{name}__float16"], [name], to=TensorProto.FLOAT))
        n += 1
    nodes = casts + list(graph.node)
    del graph.node[:]
    graph.node.extend(nodes)
    return n


def strip_node_metadata(proto) -> None:
    """Remove the exporter's per-node notes (``pkg.torch.onnx.stack_trace``, name scopes, FX node names:
    absolute source paths and line numbers of this package) from every node of ``proto`` (an
    ``onnx.ModelProto``), its functions and subgraphs, in place. They are not read by any runtime; without
    them an export's bytes depend on the checkpoint and the options only, not on where spotlights is
    installed or on edits to its source."""

    def nodes(graph):
        for node in graph.node:
            yield node
            for attr in node.attribute:
                if attr.g.node:
                    yield from nodes(attr.g)
                for g in attr.graphs:
                    yield from nodes(g)

    for node in nodes(proto.graph):
        del node.metadata_props[:]
    for fn in proto.functions:
        for node in fn.node:
            del node.metadata_props[:]
    del proto.graph.metadata_props[:]


def parity(
    checkpoint, onnx_completer: OnnxCompleter, partials: np.ndarray | None = None, extents=None, classes=None
) -> dict:
    """Largest absolute difference of every graph output, onnxruntime against the torch model of ``checkpoint``
    (float32, CPU), on ``partials`` (default: 8 seeded random clouds; box rigs: a car's box, or ``extents``;
    class-conditioned models: the (B,) int64 class rows ``classes``, default -1, 0, 1, ... in turn: no class
    and every class).

    Returns {output name: max |onnx - torch|}, plus ``kept_rays_differ``: rays kept by one and not the other.
    """
    import torch

    model = model_from_checkpoint(load_checkpoint(resolve_checkpoint(checkpoint)), torch.device("cpu"))
    x = partials if partials is not None else (np.random.default_rng(0).normal(size=(8, 256, 3)) * 0.3)
    x = np.ascontiguousarray(x, dtype=np.float32)
    dirs = None
    if getattr(model, "needs_box", False):
        e = extents if extents is not None else unit_extents(TIMING_BOX_SIZE)
        e = np.broadcast_to(np.asarray(e, dtype=np.float64), (len(x), 3))
        dirs = directions_for_extents(model.rig, e)
    graph, inputs, names = _graph_module(model)
    rows = None
    if "classes" in inputs:
        c = len(model.classes)
        rows = np.asarray(np.arange(len(x)) % (c + 1) - 1 if classes is None else classes, dtype=np.int64)
    with torch.inference_mode():
        args = (torch.from_numpy(x),) + ((torch.from_numpy(np.ascontiguousarray(dirs)),) if dirs is not None else ())
        args += (torch.from_numpy(rows),) if rows is not None else ()
        ref = graph(*args)
    ref = ref if isinstance(ref, tuple) else (ref,)
    ref = {n: t.numpy() for n, t in zip(names, ref)}
    got = onnx_completer.run(x, dirs, rows)
    out = {n: float(np.abs(got[n] - ref[n]).max()) for n in names}
    if "depths" in ref:
        keep_ref = onnx_completer.keep(ref)
        out["kept_rays_differ"] = int((onnx_completer.keep(got) != keep_ref).sum())
    return out


def export_model(
    checkpoint,
    out,
    opset: int = OPSET,
    describe: bool = True,
    check: bool = True,
    log: Callable[[str], None] = logs.info,
) -> Path:
    """``spotlights export``: :func:`export_onnx`, then (``describe``) one line about the model
    written (parameters, rig, p(hit) threshold, clip, size in MB) and, with ``check`` as well,
    the :func:`parity` of onnxruntime against torch on 8 seeded random scans (max abs difference
    per output). Returns the ``.onnx`` path."""
    path = export_onnx(checkpoint, Path(out), opset=opset)
    if not describe:
        return path
    c = load_onnx_completer(path)
    rig = f", rig {c.rig.name}" if c.rig is not None else ""
    dec = (f", p(hit) >= {c.threshold:g}" if c.threshold is not None else "") + (
        f", clip {c.clip:g}" if c.clip is not None else ""
    )
    dec += f", class input: {', '.join(c.classes)}" if c.classes else ""
    log(
        f"{checkpoint} -> {path} ({c.model_name}, {c.n_params:,} parameters{rig}{dec}; "
        f"{path.stat().st_size / 1e6:.1f} MB)"
    )
    if check:
        diff = parity(checkpoint, c)
        log(
            "parity on 8 random scans, max |onnxruntime - torch|: " + ", ".join(f"{k} {v:.1e}" for k, v in diff.items())
        )
    return path
