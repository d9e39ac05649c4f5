"""The ONNX runtime of ``spotlights export`` files: :class:`OnnxCompleter` runs an export with onnxruntime
behind the :class:`~spotlights.learning.inference.BaseCompleter` interface.

The file format (inputs, outputs, metadata) is described in :mod:`spotlights.learning.export`, which writes it;
this module reads the metadata back (checked: a damaged entry is one :class:`InputFileError`), feeds the graph and
keeps, snaps and clips the rays exactly as the torch models do (:func:`ray_points`, :func:`clip_rays_to_boxes`).
Every name here is also importable from :mod:`spotlights.learning.export`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..data.vehicle_classes import class_rows
from ..errors import InputFileError, ParameterError, SpotlightsError
from ..geometry.box_clamp import ray_box_interval
from ..geometry.evidence import snap_batch_to_observed
from .domain import LearnedDomain
from .inference import DEFAULT, BaseCompleter
from .rays import rig_rays, rig_spec

FORMAT = "spotlights-onnx"
FORMAT_VERSION = 2
"""The newest export format this spotlights reads (and writes for a graph with a ``classes`` input)."""
INSTALL_HINT = "the ONNX runtime is an optional extra: pip install 'spotlights[onnx]' (onnx, onnxruntime)"
DAMAGED = "damaged spotlights metadata"


def _require(module: str):
    """The module ``module`` imported, or a :class:`SpotlightsError` with the install hint of the ONNX extra."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise SpotlightsError(f"{module} is not installed; {INSTALL_HINT}") from None


def _parse_onnx_fields(p: Path, meta: dict[str, str]) -> tuple[int, dict]:
    """The export's format version and the completer's fields parsed from its metadata strings (not yet checked
    against each other): a missing or malformed (not JSON) entry is an :class:`InputFileError` naming the file."""
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
        raise InputFileError(p, f"{DAMAGED}: no {exc.args[0]!r} entry") from None
    except Exception as exc:  # noqa: BLE001 - any entry that does not parse is the file's fault
        first = (str(exc).splitlines() or [type(exc).__name__])[0][:100]
        raise InputFileError(p, f"{DAMAGED} ({type(exc).__name__}: {first})") from None
    return version, f


def _check_graph_fields(p: Path, f: dict) -> None:
    """Raise :class:`InputFileError` when the parsed inputs, outputs, clip, threshold or box rig do not fit together."""
    if not all(isinstance(v, list) and all(isinstance(n, str) for n in v) for v in (f["inputs"], f["outputs"])):
        raise InputFileError(p, f"{DAMAGED}: inputs/outputs are not lists of names")
    if "partial" not in f["inputs"]:
        raise InputFileError(p, f"{DAMAGED}: no 'partial' input")
    if "points" not in f["outputs"] and not {"depths", "ray_points"} <= set(f["outputs"]):
        raise InputFileError(p, f"{DAMAGED}: outputs hold neither 'points' nor 'depths' with 'ray_points'")
    if any(not isinstance(f[k], (int, float, type(None))) or isinstance(f[k], bool) for k in ("clip", "threshold")):
        raise InputFileError(p, f"{DAMAGED}: clip/threshold are not numbers")
    if "hit_probability" in f["outputs"] and f["threshold"] is None:
        raise InputFileError(p, f"{DAMAGED}: a p(hit) output without a threshold")
    if f["needs_box"] and (f["rig"] is None or "directions" not in f["inputs"]):
        raise InputFileError(p, f"{DAMAGED}: a box-targeted model without its rig or a 'directions' input")


def _check_class_fields(p: Path, f: dict) -> None:
    """Raise :class:`InputFileError` when the class vocabulary is not distinct names or does not match the inputs."""
    vocab = f["classes"]
    if not isinstance(vocab, list) or not all(isinstance(c, str) for c in vocab) or len(set(vocab)) != len(vocab):
        raise InputFileError(p, f"{DAMAGED}: classes is not a list of distinct class names")
    if bool(vocab) != ("classes" in f["inputs"]):
        raise InputFileError(p, f"{DAMAGED}: a class vocabulary without a 'classes' input, or the reverse")


def _onnx_fields(p: Path, meta: dict[str, str]) -> dict:
    """The completer's fields from an export's metadata strings, checked: any missing, malformed
    (not JSON) or inconsistent entry is an :class:`InputFileError` naming the file."""
    version, f = _parse_onnx_fields(p, meta)
    if version > FORMAT_VERSION:
        raise InputFileError(p, f"ONNX export format {version} is newer than this spotlights ({FORMAT_VERSION})")
    _check_graph_fields(p, f)
    _check_class_fields(p, f)
    f["needs_box"] = bool(f["needs_box"])
    f["classes"] = tuple(f["classes"])
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
