"""Occlusion-aware snapping, the prototype (superseded: the package's ``snap_to_observed`` applies the rule
itself, with ``sensor=``; kept to reproduce ``occlusion_{kenney,val}.txt``; its threshold is
``dt > R`` in normalised depth, the package's ``2 dt > R``): does the snap's gain survive when a kept ray may not
snap onto an observed point more than R behind its predicted surface, unless that surface lies in observed free
space (carved from the sensor, ``carved_depths``)?

Prints accuracy / completeness / CD-L1 / F@0.01 of the default without snapping, with ``--snap 0.05``, with the
occlusion rule, with ``--snap 0.08 --snap-mirror`` and with the rule on that (the first MAX_VIEWS views of SPLIT)::

    python benchmarks/snap_occlusion.py kenney-test.h5 20 test > docs/results/fair/snap/occlusion_kenney.txt
    python benchmarks/snap_occlusion.py cars.h5 25 val > docs/results/fair/snap/occlusion_val.txt
"""

import sys

import numpy as np
import torch
from torch.utils.data import DataLoader

from spotlights.geometry.evidence import EvidenceParams, carved_depths, snap_to_observed
from spotlights.learning.checkpoint import load_checkpoint, model_from_checkpoint, resolve_checkpoint
from spotlights.learning.data import TorchCompletionDataset
from spotlights.learning.inference import mirrored
from spotlights.learning.rays import DirectionTable
from spotlights.metrics.completion import evaluate_completions

torch.set_num_threads(1)
data, maxv, split = sys.argv[1], int(sys.argv[2]), sys.argv[3]
model = model_from_checkpoint(load_checkpoint(resolve_checkpoint("default")), torch.device("cpu"))
model.eval()
ds = TorchCompletionDataset(data, split, rig=False, max_views=maxv, partials_in_memory=True)
dense = ds.gt_dense()
rays = DirectionTable(model.rig, ds.extents)
V = {
    "base": None,
    "snap05": (0.05, False, False),
    "occl05": (0.05, False, True),
    "mir08": (0.08, True, False),
    "occl_mir08": (0.08, True, True),
}
preds = {k: [] for k in V}
o = model.origins.numpy().astype(np.float64)
with torch.inference_mode():
    for batch in DataLoader(ds, batch_size=32, shuffle=False):
        out = model(*model.forward_inputs(batch, rays))
        dirs = rays.directions(batch["model"])
        keep0 = (model.hit_probabilities(out) >= model.threshold).numpy()
        dep0 = out["depths"].float().numpy().astype(np.float64)
        for b in range(len(dep0)):
            d = dirs[b].numpy().astype(np.float64)
            p = batch["partial"][b].numpy().astype(np.float64)
            sensor = batch["sensor_origin"][b].numpy().astype(np.float64)
            carve = None
            for k, v in V.items():
                if v is None:
                    dd, kk = dep0[b], keep0[b]
                else:
                    r, mir, occl = v
                    q = mirrored(p) if mir else p
                    dd, kk, sn = snap_to_observed(q, o, d, model.rig.n_secondary, dep0[b], keep0[b], r)
                    if occl:
                        if carve is None:
                            carve = carved_depths(p, o, d, sensor, EvidenceParams())
                        c = carve
                        h = c["half_chord"]
                        nt = c["carved"].shape[1]
                        j = np.minimum(np.floor(np.clip(dep0[b], 0, h) / np.where(h > 0, h, 1) * nt), nt - 1).astype(
                            int
                        )
                        in_free = c["carved"][np.arange(len(j)), j]
                        behind = keep0[b] & sn & (dd > dep0[b] + r) & ~in_free
                        dd = np.where(behind, dep0[b], dd)
                pts = model.kept_points(
                    torch.from_numpy(dd[None]).float(), torch.from_numpy(kk[None]), None, dirs[b : b + 1]
                )[0]
                preds[k].append(pts.numpy())
for k in V:
    per = evaluate_completions(preds[k], ds.sample_models, dense, 0.01, True, {})
    print(
        k,
        {m: round(float(np.nanmean(per[m])), 5) for m in ("accuracy", "completeness", "chamfer_l1", "fscore")},
        flush=True,
    )
