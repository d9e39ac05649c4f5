"""The paper's numbers (Tables 1-5 of *Spotlights*), copied from ``shared/paper/spotlights.tex``.

One dict per table, keyed the way :mod:`spotlights.experiments.reproduce` reports our
numbers, so that a row of ours and the paper's row sit side by side. Units are the
paper's: accuracy and completeness are one-sided Chamfer distances in the unit frame
(object in its circumscribed unit sphere), consistency is the two-sided CD of Eq. (1),
hit ratios are per cent, parameters in millions, runtimes in milliseconds (the paper's
GPU). ``tests/test_reproduce.py`` checks every value against the ``.tex`` file.
"""

from __future__ import annotations

CAR_CATEGORIES = ("hatchback", "sedan", "suv")
"""Table 1 and 5 columns (the paper's CARLA body types; our ApolloScape car folders)."""

REAL_CLASSES = ("car", "truck", "caravan", "trailer")
"""Table 2 columns (KITTI-360 vehicle classes)."""

ABLATION_CATEGORIES = ("bathtub", "bottle", "cabinet", "chair", "lamp", "sofa")
"""Table 3 and 4 columns (the paper's 6 ShapeNet categories)."""

METHODS = ("atlasnet", "pcn", "foldingnet", "topnet", "sanet")
"""Table 1 and 2 row order of the paper (registry names)."""

# Table 1: accuracy (one-sided CD prediction -> 16,384-point GT), #params (M), runtime (ms).
# Rows: registry name, or "sanet (no clip)" / "sanet (clip 0.2)".
TABLE1 = {
    "atlasnet": {
        "hatchback": 0.06586,
        "sedan": 0.07325,
        "suv": 0.06051,
        "average": 0.06462,
        "params_m": 8.3,
        "runtime_ms": 14.1,
    },
    "pcn": {
        "hatchback": 0.02528,
        "sedan": 0.02842,
        "suv": 0.02221,
        "average": 0.02428,
        "params_m": 7.6,
        "runtime_ms": 34.1,
    },
    "foldingnet": {
        "hatchback": 0.02437,
        "sedan": 0.02701,
        "suv": 0.02166,
        "average": 0.02345,
        "params_m": 8.5,
        "runtime_ms": 34.6,
    },
    "topnet": {
        "hatchback": 0.02396,
        "sedan": 0.02631,
        "suv": 0.02051,
        "average": 0.02252,
        "params_m": 7.5,
        "runtime_ms": 37.9,
    },
    "sanet (no clip)": {
        "hatchback": 0.02356,
        "sedan": 0.03095,
        "suv": 0.02171,
        "average": 0.02442,
        "params_m": 0.9,
        "runtime_ms": 0.80,
    },
    "sanet (clip 0.2)": {
        "hatchback": 0.02124,
        "sedan": 0.02775,
        "suv": 0.01850,
        "average": 0.02133,
        "params_m": 0.9,
        "runtime_ms": 1.05,
    },
}

# Table 2: consistency on KITTI-360 (mean CD between completions of one object in different frames).
TABLE2 = {
    "atlasnet": {"car": 0.0649, "truck": 0.0674, "caravan": 0.0651, "trailer": 0.0710, "average": 0.0671},
    "pcn": {"car": 0.0493, "truck": 0.0612, "caravan": 0.0644, "trailer": 0.0580, "average": 0.0582},
    "foldingnet": {"car": 0.0514, "truck": 0.0611, "caravan": 0.0629, "trailer": 0.0595, "average": 0.0587},
    "topnet": {"car": 0.0513, "truck": 0.0644, "caravan": 0.0648, "trailer": 0.0593, "average": 0.0599},
    "sanet": {"car": 0.0410, "truck": 0.0576, "caravan": 0.0613, "trailer": 0.0498, "average": 0.0524},
}

# Table 3: completeness (one-sided CD 16,384 GT points -> Spotlights points), keyed (rays, angle in degrees).
TABLE3 = {
    (2048, 30): {
        "bathtub": 0.0474,
        "bottle": 0.0547,
        "cabinet": 0.0678,
        "chair": 0.0444,
        "lamp": 0.0426,
        "sofa": 0.0619,
        "average": 0.0506,
    },
    (2048, 60): {
        "bathtub": 0.0349,
        "bottle": 0.0380,
        "cabinet": 0.0450,
        "chair": 0.0339,
        "lamp": 0.0352,
        "sofa": 0.0447,
        "average": 0.0376,
    },
    (2048, 83): {
        "bathtub": 0.0382,
        "bottle": 0.0397,
        "cabinet": 0.0457,
        "chair": 0.0389,
        "lamp": 0.0407,
        "sofa": 0.0469,
        "average": 0.0415,
    },
    (4096, 30): {
        "bathtub": 0.0326,
        "bottle": 0.0367,
        "cabinet": 0.0476,
        "chair": 0.0302,
        "lamp": 0.0298,
        "sofa": 0.0450,
        "average": 0.0353,
    },
    (4096, 60): {
        "bathtub": 0.0260,
        "bottle": 0.0278,
        "cabinet": 0.0349,
        "chair": 0.0253,
        "lamp": 0.0263,
        "sofa": 0.0346,
        "average": 0.0285,
    },
    (4096, 83): {
        "bathtub": 0.0290,
        "bottle": 0.0297,
        "cabinet": 0.0361,
        "chair": 0.0293,
        "lamp": 0.0312,
        "sofa": 0.0367,
        "average": 0.0318,
    },
    (8192, 30): {
        "bathtub": 0.0233,
        "bottle": 0.0259,
        "cabinet": 0.0345,
        "chair": 0.0216,
        "lamp": 0.0212,
        "sofa": 0.0331,
        "average": 0.0255,
    },
    (8192, 60): {
        "bathtub": 0.0197,
        "bottle": 0.0208,
        "cabinet": 0.0279,
        "chair": 0.0192,
        "lamp": 0.0200,
        "sofa": 0.0274,
        "average": 0.0220,
    },
    (8192, 83): {
        "bathtub": 0.0222,
        "bottle": 0.0225,
        "cabinet": 0.0294,
        "chair": 0.0223,
        "lamp": 0.0244,
        "sofa": 0.0295,
        "average": 0.0248,
    },
}

# Table 4: hit ratio (%) per opening angle (degrees); the ray count is not stated.
TABLE4 = {
    30: {"bathtub": 93.8, "bottle": 81.6, "cabinet": 93.9, "chair": 79.1, "lamp": 47.2, "sofa": 85.0, "average": 78.6},
    60: {"bathtub": 63.4, "bottle": 45.2, "cabinet": 67.0, "chair": 49.1, "lamp": 31.5, "sofa": 57.1, "average": 50.9},
    83: {"bathtub": 43.2, "bottle": 29.9, "cabinet": 47.7, "chair": 32.6, "lamp": 22.6, "sofa": 39.8, "average": 34.8},
}

# Table 5: SA-Net accuracy (with clip) per sampling resolution N*M.
TABLE5 = {
    "32x64": {"hatchback": 0.02124, "sedan": 0.02775, "suv": 0.01850, "average": 0.02133},
    "64x32": {"hatchback": 0.02219, "sedan": 0.02771, "suv": 0.01907, "average": 0.02179},
    "256x64": {"hatchback": 0.02058, "sedan": 0.02700, "suv": 0.01839, "average": 0.02098},
}

PAPER_TABLES = {1: TABLE1, 2: TABLE2, 3: TABLE3, 4: TABLE4, 5: TABLE5}
"""Table number -> the dict above."""
