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
the ONNX runtime. :class:`OnnxCompleter` runs a file with onnxruntime (the optional extra
``spotlights[onnx]``) and has the :class:`~spotlights.learning.inference.Completer` interface
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
from typing import Any

import numpy as np

from .. import logs
from .._version import __version__
from ..data.vehicle_classes import class_rows
from ..errors import InputFileError, ParameterError, SpotlightsError
from ..geometry.box_clamp import ray_box_interval
from ..geometry.boxes import unit_extents
from ..geometry.evidence import snap_batch_to_observed
from ..outputs import atomic_output
from .checkpoint import load_checkpoint, model_from_checkpoint, resolve_checkpoint
from .domain import LearnedDomain
from .inference import DEFAULT, BaseCompleter
from .rays import TIMING_BOX_SIZE, directions_for_extents, rig_rays, rig_spec, timing_directions

FORMAT = "spotlights-onnx"
FORMAT_VERSION = 2
"""The newest export format this spotlights reads (and writes for a graph with a ``classes`` input)."""
BASE_FORMAT_VERSION = 1
"""The format of an export without a class input (unchanged since version 1)."""
OPSET = 18
# The lowest opset torch's exporter converts its graphs to (it writes 18 and converts; below 15 it
# kept 18 without a word, measured with torch 2.13 / onnxscript); the highest is the newest the
# installed onnx knows.
MIN_OPSET = 15
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
    newest = int(onnx.defs.onnx_opset_version())
    if not MIN_OPSET <= int(opset) <= newest:
        raise ParameterError(
            f"`opset` {opset}: ONNX opsets {MIN_OPSET} to {newest} can be written (default {OPSET})", "opset"
        )
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
    vocab = list(model.classes) if getattr(model, "class_embedding", None) is not None else None
    if vocab is not None:  # a class row and "no class" (-1): both paths of SANet.encode are traced
        args, shapes["classes"] = (*args, torch.tensor([0, -1], dtype=torch.int64)), {0: b}
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


def _onnx_fields(p: Path, meta: dict[str, str]) -> dict:
    """The completer's fields from an export's metadata strings, checked: any missing, malformed
    (not JSON) or inconsistent entry is an :class:`InputFileError` naming the file."""
    try:
        version = int(meta.get("spotlights_format_version", "0"))
        f = {
            "model_name": meta["model_name"],
            "param_counts": json.loads(meta["param_counts"]),
            "rig": json.loads(meta.get("rig", "null")),
            "needs_box": json.loads(meta.get("needs_box", "false")),
            "clip": json.loads(meta.get("clip", "null")),
            "threshold": json.loads(meta.get("threshold", "null")),
            "domain": LearnedDomain.from_checkpoint({"domain": json.loads(meta.get("domain", "null"))}),
            "outputs": json.loads(meta["outputs"]),
            "inputs": json.loads(meta["inputs"]),
            "classes": json.loads(meta.get("classes", "[]")),
        }
        if f["rig"] is not None:
            f["rig"] = rig_spec(f["rig"])
        int(f["param_counts"]["total"])
    except KeyError as exc:
        raise InputFileError(p, f"damaged spotlights metadata: no {exc.args[0]!r} entry") from None
    except Exception as exc:  # noqa: BLE001 - any entry that does not parse is the file's fault
        first = (str(exc).splitlines() or [type(exc).__name__])[0][:100]
        raise InputFileError(p, f"damaged spotlights metadata ({type(exc).__name__}: {first})") from None
    if version > FORMAT_VERSION:
        raise InputFileError(p, f"ONNX export format {version} is newer than this spotlights ({FORMAT_VERSION})")
    damaged = "damaged spotlights metadata"
    if not all(isinstance(v, list) and all(isinstance(n, str) for n in v) for v in (f["inputs"], f["outputs"])):
        raise InputFileError(p, f"{damaged}: inputs/outputs are not lists of names")
    if "partial" not in f["inputs"]:
        raise InputFileError(p, f"{damaged}: no 'partial' input")
    if "points" not in f["outputs"] and not {"depths", "ray_points"} <= set(f["outputs"]):
        raise InputFileError(p, f"{damaged}: outputs hold neither 'points' nor 'depths' with 'ray_points'")
    if any(not isinstance(f[k], (int, float, type(None))) or isinstance(f[k], bool) for k in ("clip", "threshold")):
        raise InputFileError(p, f"{damaged}: clip/threshold are not numbers")
    if "hit_probability" in f["outputs"] and f["threshold"] is None:
        raise InputFileError(p, f"{damaged}: a p(hit) output without a threshold")
    if f["needs_box"] and (f["rig"] is None or "directions" not in f["inputs"]):
        raise InputFileError(p, f"{damaged}: a box-targeted model without its rig or a 'directions' input")
    vocab = f["classes"]
    if not isinstance(vocab, list) or not all(isinstance(c, str) for c in vocab) or len(set(vocab)) != len(vocab):
        raise InputFileError(p, f"{damaged}: classes is not a list of distinct class names")
    if bool(vocab) != ("classes" in f["inputs"]):
        raise InputFileError(p, f"{damaged}: a class vocabulary without a 'classes' input, or the reverse")
    f["needs_box"] = bool(f["needs_box"])
    f["classes"] = tuple(vocab)
    return f


def _unloadable(path: Path, exc: Exception) -> str:
    """Why onnxruntime could not load ``path`` (its error ``exc``), in a few words: not an ONNX file at all (when
    the onnx package can tell), or a graph onnxruntime cannot run."""
    try:
        import onnx

        onnx.load(str(path), load_external_data=False)
    except ImportError:
        pass
    except Exception as bad:  # noqa: BLE001 - any parse failure is a bad file
        return f"not a readable ONNX file ({str(bad).splitlines()[0][:100]})"
    return f"onnxruntime cannot load this graph ({str(exc).splitlines()[0][:100]})"


class OnnxCompleter(BaseCompleter):
    """A ``spotlights export`` ONNX file run with onnxruntime: a
    :class:`~spotlights.learning.inference.BaseCompleter` (same ``complete``, same results as the torch
    :class:`~spotlights.learning.inference.Completer` up to float rounding) whose forward pass is the graph.

    Attributes: ``model_name``, ``n_params``, ``param_counts``, ``rig`` (RigSpec or None),
    ``clip``, ``threshold``, ``needs_box``, ``domain`` (:class:`~spotlights.learning.domain.LearnedDomain`),
    ``classes`` (the class vocabulary of a class-conditioned export, in row order; ``()`` for the others, which
    complete every box as the car models they are), ``path``, ``session`` (the onnxruntime session),
    ``device`` (``"onnxruntime:CPUExecutionProvider"`` or the first provider used), ``runtime`` (``"onnx"``) and
    ``precision`` (``"fp32"``: the graph runs as exported).
    """

    runtime = "onnx"
    precision = "fp32"

    def __init__(self, path, threads: int | None = None, providers=None):
        ort = _require("onnxruntime")
        p = Path(path)
        if not p.is_file():
            raise InputFileError(p, "no such ONNX file")
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = int(threads)
        try:  # the metadata is read from the InferenceSession: the onnx package is not imported (a tenth of a second)
            self.session = ort.InferenceSession(str(p), opts, providers=providers or ["CPUExecutionProvider"])
        except Exception as exc:  # noqa: BLE001 - a file onnxruntime cannot run is a bad file
            raise InputFileError(p, _unloadable(p, exc)) from None
        meta = dict(self.session.get_modelmeta().custom_metadata_map)
        if meta.get("spotlights_format") != FORMAT:
            raise InputFileError(
                p,
                "not a spotlights ONNX export (no spotlights_format metadata; make one with "
                "'spotlights export CHECKPOINT --out model.onnx')",
            )
        fields = _onnx_fields(p, meta)
        graph_inputs = {i.name for i in self.session.get_inputs()}
        graph_outputs = {o.name for o in self.session.get_outputs()}
        missing = [n for n in fields["inputs"] if n not in graph_inputs] + [
            n for n in fields["outputs"] if n not in graph_outputs
        ]
        if missing:
            raise InputFileError(p, f"damaged spotlights metadata: the graph has no {missing[0]!r} input or output")
        self.path = p
        self.meta = meta
        for key, value in fields.items():
            setattr(self, key, value)
        self.n_params = int(self.param_counts["total"])
        self.device = f"onnxruntime:{self.session.get_providers()[0]}"

    def __repr__(self):
        return f"OnnxCompleter({self.model_name}, {self.n_params:,} parameters, {self.path})"

    def run(self, partials: np.ndarray, directions: np.ndarray | None = None, classes=None) -> dict:
        """Raw graph outputs {name: array} of (B, K, 3) float32 partials (and (B, N*M, 3) directions for box rigs;
        for a class-conditioned export (B,) integer ``classes``, rows of :attr:`classes`, -1 or None: no class).

        Raises :class:`ParameterError` (one line) for class rows that are not a (B,) integer array of -1 to
        C - 1, or given to an export without a class input."""
        feed = {"partial": np.ascontiguousarray(partials, dtype=np.float32)}
        if "directions" in self.inputs:
            feed["directions"] = np.ascontiguousarray(directions, dtype=np.float32)
        if "classes" in self.inputs:
            feed["classes"] = self.class_input(classes, len(feed["partial"]))
        elif classes is not None:
            raise ParameterError(
                f"{self.path.name} has no class input (not a class-conditioned model): run it without classes"
            )
        return dict(zip(self.outputs, self.session.run(self.outputs, feed)))

    def class_input(self, classes, n: int) -> np.ndarray:
        """The graph's ``classes`` input: (n,) int64 rows of :attr:`classes` (None: -1 each, no class), checked."""
        if classes is None:
            return np.full(n, -1, dtype=np.int64)
        a = np.asarray(classes)
        rows = f"-1 (no class) or 0..{len(self.classes) - 1} ({', '.join(self.classes)})"
        if a.dtype.kind not in "iu" or a.shape != (n,):
            raise ParameterError(
                f"{self.path.name}: classes must be a ({n},) integer array of class rows {rows}, got "
                f"{a.dtype} of shape {a.shape} (class names go through complete(classes=...))"
            )
        bad = a[(a < -1) | (a >= len(self.classes))]
        if len(bad):
            raise ParameterError(f"{self.path.name}: class row {int(bad[0])} is not one of {rows}")
        return a.astype(np.int64)

    def keep(self, out: dict, clip=DEFAULT) -> np.ndarray:
        """(B, N*M) bool rays a completion keeps (the torch models' rule; see the module docstring)."""
        c = self.clip if clip is DEFAULT else clip
        depths = out["depths"]
        mask = out["hit_probability"] >= np.float32(self.threshold) if "hit_probability" in out else depths > 0
        if c is not None:
            mask &= depths >= np.float32(c)
        return mask

    def _forward(
        self,
        partials: np.ndarray,
        clip: Any,
        directions: np.ndarray | None,
        sensor_origins: np.ndarray | None = None,
        classes=None,
        box_half: np.ndarray | None = None,
        inside: list | None = None,
        snap=None,
    ) -> list[np.ndarray]:
        """One batch through onnxruntime; the rays kept as the torch models keep them (:meth:`keep`), snapped to
        the observed points with ``snap`` (a :class:`~spotlights.geometry.evidence.SnapTargets`) as the torch
        SA-Nets snap them (:func:`~spotlights.geometry.evidence.snap_to_observed`). Exports hold
        no free-space model (``spotlights export`` refuses ``sanet-local``), so ``sensor_origins`` is unused;
        ``classes`` (b names or None) feed a class-conditioned export's ``classes`` input as the torch
        ``Completer`` feeds its model (:func:`~spotlights.data.vehicle_classes.class_rows`; other exports ignore
        them); with ``box_half`` the kept rays are clipped to each box along the rays as the torch SA-Nets clip
        them (:func:`clip_rays_to_boxes`)."""
        rows = class_rows(classes, self.classes) if classes is not None and self.classes else None
        out = self.run(partials, directions, rows)
        if "points" in out:
            return [np.ascontiguousarray(p, dtype=np.float32) for p in out["points"]]
        if snap is not None and self.rig is None:
            raise ParameterError(f"{self.path.name}: snapping to the observed points needs a ray model (an SA-Net)")
        mask = self.keep(out, clip)
        points, depths = out["ray_points"], out["depths"]
        if self.rig is not None and (snap is not None or box_half is not None):
            origins, fixed = rig_rays(self.rig)
            dirs = fixed if directions is None else directions
        if snap is not None:  # as the torch SA-Nets snap (SANet.snap_rays), then decoded as they decode
            depths, mask = snap_batch_to_observed(snap, origins, dirs, rig_spec(self.rig).n_secondary, depths, mask)
            depths = depths.astype(np.float32)  # as the torch models keep their depths
            points = ray_points(depths, origins, dirs)
        if box_half is not None and self.rig is not None:
            points, mask, share = clip_rays_to_boxes(depths, mask, origins, dirs, box_half)
            if inside is not None:
                inside.extend(float(v) for v in share)
        return [p[m].astype(np.float32) for p, m in zip(points, mask)]


def ray_points(depths, origins, directions) -> np.ndarray:
    """(B, R, 3) float32 ``o + 2 d u`` of depths (B, R) on rays ``origins`` (R, 3) and ``directions`` (R, 3) or
    (B, R, 3), each depth clamped to [0, half the ray's chord through the unit sphere] (the torch SA-Nets'
    :meth:`~spotlights.learning.models.sanet.SANet.ray_points`)."""
    o = np.asarray(origins, dtype=np.float32)
    u = np.broadcast_to(np.asarray(directions, dtype=np.float32), (len(depths), *o.shape))
    half_chord = np.maximum(-(o * u).sum(-1), 0.0)
    d = np.minimum(np.maximum(np.asarray(depths, dtype=np.float32), 0.0), half_chord)
    return o + (2.0 * d)[..., None] * u


def clip_rays_to_boxes(depths, keep, origins, directions, box_half) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The numpy form of :meth:`spotlights.learning.models.sanet.SANet.clip_to_boxes` then its ray points.

    depths (B, R) raw regressed depths; keep (B, R) bool kept rays; origins (R, 3); directions (R, 3) or
    (B, R, 3) unit rays; box_half (B, 3) unit-frame box half-extents. Returns ``(points (B, R, 3) float32,
    keep (B, R) bool, inside (B,) float64)``: each kept depth clipped into ``[max(t_in, 0), t_out] / 2`` of its
    ray through the box (a kept ray that misses the box dropped), then to half the ray's chord through the unit
    sphere, decoded as ``o + 2 d u``; ``inside`` the share of kept rays inside before the clip.
    """
    o = np.asarray(origins, dtype=np.float64)
    u = np.broadcast_to(np.asarray(directions, dtype=np.float64), (len(depths), *o.shape))
    t_in, t_out = ray_box_interval(o, u, np.asarray(box_half, dtype=np.float64)[:, None, :])
    meets = (t_in <= t_out) & (t_out > 0)
    t = 2.0 * np.maximum(np.asarray(depths, dtype=np.float64), 0.0)
    was_in = keep & meets & (t >= t_in) & (t <= t_out)
    n = keep.sum(-1)
    inside = np.where(n > 0, was_in.sum(-1) / np.maximum(n, 1), 1.0)
    keep = keep & meets
    d = np.where(keep, np.minimum(np.maximum(t, np.maximum(t_in, 0.0)), t_out) / 2.0, depths).astype(np.float32)
    return ray_points(d, o, u), keep, inside


def load_onnx_completer(path, threads: int | None = None) -> OnnxCompleter:
    """An :class:`OnnxCompleter` for a ``spotlights export`` file (one-line errors; install hint without onnxruntime)."""
    return OnnxCompleter(path, threads=threads)


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
