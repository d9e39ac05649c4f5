"""Where the observed points of AV2's tracked cars lie that a completion misses (docs/studies/car-model.md).

Usage: PYTHONPATH=src python benchmarks/fidelity_misses.py av2.h5 > docs/results/car_model/fidelity_misses.txt
(av2.h5: `spotlights real extract ../shared/data/lidar/argoverse2 --format av2
--classes car,truck,caravan,trailer,bus,construction,emergency --out av2.h5`).
Every car observation's 256 stored points (unit frame) against the completion of the default and the class model:
a point is missed when it lies farther than 0.08 unit from the completion; "interior" = inside the box shrunk to 70%.
The mean distance of the observed points to the completion is a proxy of fidelity over these 59 observations (the
reported fidelity is per tracked car over its raw points); printed with and without the interior points, and the
interior points' share of the summed distance.
"""

import sys

import numpy as np
from scipy.spatial import cKDTree

import spotlights
from spotlights.data.real.extract import read_observations

obs = read_observations(sys.argv[1])
idx = [i for i in range(len(obs)) if obs.cls[i] == "car"]
partials = obs.partial[idx]
half = obs.box_size[idx] / np.linalg.norm(obs.box_size[idx], axis=1, keepdims=True)  # unit-frame half extents
interior = (np.abs(partials) < 0.7 * half[:, None, :]).all(axis=2)
print(f"{len(idx)} car observations; observed points in the interior: {interior.mean():.0%}")
for name in ("default", "classes"):
    c = spotlights.load_completer(name, device="cpu")
    extra = {"classes": ["car"] * len(idx)} if name == "classes" else {}
    outs = c.complete(partials, extents=half.astype(np.float32), sensor_origins=obs.sensor_origin[idx], **extra)
    dist = np.stack([cKDTree(o).query(p)[0] for o, p in zip(outs, partials)])
    missed = dist > 0.08
    share = (missed & interior).sum() / missed.sum()
    print(f"{name}: missed points {missed.sum()} of {missed.size}; {share:.0%} of them in the interior")
    print(
        f"{name}: mean distance {dist.mean():.4f} (interior points left out: {dist[~interior].mean():.4f}); "
        f"the interior points hold {dist[interior].sum() / dist.sum():.0%} of the summed distance"
    )
