"""Picking the better of two models per object (synthetic only, docs/studies/car-model.md): per scan of the paper's test cars (cars.h5, 700 scans),
complete with the default and the class model and keep the completion with the lower fidelity to the scan (what
the heading check does for two headings); is its accuracy <= 0.0153 (the rule's condition 1)?

Usage: PYTHONPATH=src python benchmarks/pick_per_object.py cars.h5 > docs/results/car_model/pick_per_object.txt
(cars.h5: docs/dataset.md, the paper's build)."""

import sys

import numpy as np
from scipy.spatial import cKDTree

import spotlights
from spotlights.learning.data import TorchCompletionDataset
from spotlights.metrics.consistency import fidelity

ds = TorchCompletionDataset(sys.argv[1], "test", rig=False, max_views=100, partials_in_memory=True)
dense = ds.gt_dense()
models = ds.sample_models
parts = np.stack([ds[i]["partial"].numpy() for i in range(len(ds))])
origins = np.stack([ds[i]["sensor_origin"].numpy() for i in range(len(ds))])
ext = ds.extents[models].astype(np.float32)
res = {}
for name in ("default", "classes"):
    c = spotlights.load_completer(name, device="cpu")
    extra = {"classes": ["car"] * len(parts)} if name == "classes" else {}
    outs = c.complete(parts, extents=ext, sensor_origins=origins, **extra)
    acc = np.array([cKDTree(dense[int(m)]).query(o)[0].mean() for o, m in zip(outs, models)])
    fid = np.array([fidelity(p, o) for p, o in zip(parts, outs)])
    res[name] = (acc, fid)
    print(name, "accuracy", acc.mean().round(5), "fidelity", fid.mean().round(4), flush=True)
pick = res["classes"][1] < res["default"][1]
acc = np.where(pick, res["classes"][0], res["default"][0])
oracle = np.minimum(res["classes"][0], res["default"][0])
print(
    f"selected by fidelity: accuracy {acc.mean():.5f}; class model chosen for {pick.mean():.0%}; oracle {oracle.mean():.5f}"
)
