"""Synthetic completion dataset: simulated LiDAR partial scans + per-model ground truth.

The paper's recipe (Section 5.1) for any folder of meshes: every model gets
``views`` partial observations from a simulated spinning LiDAR (see
:mod:`spotlights.data.lidar`), each resampled to 256 points, and one ground
truth shared by its observations: 2048 and 16384 uniform surface points and the
Spotlights depth arrays of one or more rigs. Everything of a sample lives in the
unit frame of the vehicle's box (the paper's normalisation), and the transform
from the sensor frame is stored with each sample.

The package, one concern per module:

* :mod:`.config` -- :class:`BuildConfig` (everything that determines the content), rig and
  split specs;
* :mod:`.catalogue` -- the mesh catalogue: discovery (folders, manifests), loading, splits;
* :mod:`.simulate` -- one work unit, arrays in and arrays out (ground truth of a model, a block
  of its views);
* :mod:`.runner` -- the resumable build: plan, process pool, parts folder, consolidation
  (:class:`BuildSettings`: how a build runs);
* :mod:`.request` -- :class:`BuildRequest`: the options of ``spotlights dataset build`` as one object;
* :mod:`.addrig` -- ``dataset add-rig``.

Work and determinism
--------------------
Work units are (model, ground truth) and (model, block of views). Every random
number of view ``v`` of model ``m`` comes from
``SeedSequence(seed, spawn_key=(model_key(name_m), 1, v))`` (ground truth: stream
2 and 3), where ``model_key`` is a hash of the model's name: results depend on
neither the number of workers, nor the order of completion, nor the block size,
nor which other meshes are in the folder.
"""

from .addrig import AddRigReport, add_rig
from .catalogue import LoadedModel, ModelEntry, assign_splits, discover_models, load_model, model_key
from .config import (
    PLAN_VERSION,
    SENSOR_CLEARANCE,
    STREAM_GT_DENSE,
    STREAM_GT_POINTS,
    STREAM_SPLIT,
    STREAM_VIEWS,
    BuildConfig,
    parse_rig,
    parse_split,
)
from .request import BuildRequest, build_from_request, build_summary
from .runner import BuildReport, BuildSettings, build_dataset, save_npz_atomic
from .simulate import compute_unit, model_ground_truth, simulate_views, unit_rng

__all__ = [
    "AddRigReport",
    "BuildConfig",
    "BuildReport",
    "BuildRequest",
    "BuildSettings",
    "LoadedModel",
    "ModelEntry",
    "PLAN_VERSION",
    "SENSOR_CLEARANCE",
    "STREAM_GT_DENSE",
    "STREAM_GT_POINTS",
    "STREAM_SPLIT",
    "STREAM_VIEWS",
    "add_rig",
    "assign_splits",
    "build_dataset",
    "build_from_request",
    "build_summary",
    "compute_unit",
    "discover_models",
    "load_model",
    "model_ground_truth",
    "model_key",
    "parse_rig",
    "parse_split",
    "save_npz_atomic",
    "simulate_views",
    "unit_rng",
]
