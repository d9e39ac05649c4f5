"""What a reproduction computes: its settings and the runs, rigs and ray counts of the tables."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

# Table 1 runs in the paper's row order, and every run: name -> (model, rig or None = default rig).
TABLE1_RUNS = ("atlasnet", "pcn", "foldingnet", "topnet", "sanet")
TABLE5_RUNS = {"32x64": "sanet", "64x32": "sanet-64x32", "256x64": "sanet-256x64"}
RUNS = {
    "sanet": ("sanet", None),
    "pcn": ("pcn", None),
    "foldingnet": ("foldingnet", None),
    "topnet": ("topnet", None),
    "atlasnet": ("atlasnet", None),
    "sanet-64x32": ("sanet", "cap-64x32-60"),
    "sanet-256x64": ("sanet", "cap-256x64-60"),
    "sanet-box": ("sanet", "box-32x64-ellipsoid-s1"),
}
BOX_RIG = "box-32x64-ellipsoid-s1"
"""The box-targeted rig of the box table (docs/box-rig.md): ``--rig-kind box`` at 2048 rays, the default box rig."""
BOX_RUNS = {"paper": "sanet", "box": "sanet-box"}  # the box table's SA-Net pair: paper rig (Table 1 run) vs box rig
DISPLAY = {
    "sanet": "SA-Net",
    "sanet-box": "SA-Net (box rig)",
    "pcn": "PCN",
    "foldingnet": "FoldingNet",
    "topnet": "TopNet",
    "atlasnet": "AtlasNet",
}
ANGLE_LABELS = {"cap 30": 30, "cap 60": 60, "cap 83 (r = R/4)": 83}
BOX_STUDY_LABELS = ("box ellipsoid s1", "box volume s0.9")
"""Box rigs of ``rig_study.BOX_RIGS`` studied beside the cap rigs (the default box rig and the Halton volume s0.9)."""
ABLATION_RAYS = (2048, 4096, 8192)
HIT_RATIO_RAYS = 2048
REQUIRED_RIGS = ("cap-32x64-60", "cap-64x32-60", "cap-256x64-60")
"""The rigs a car dataset needs for Tables 1 and 5."""


@dataclass(frozen=True)
class Settings:
    """What a reproduction computes (all paths as the user gave them).

    quick : small data and the tiny ``quick`` schedule (a smoke run of every stage).
    schedule : training schedule of new runs (packaged name or YAML).
    cars_meshes, category_meshes, lidar : the shared data folders.
    cars_data : an existing car dataset to use instead of building ``OUT/data/cars.h5``.
    eval_views : test views per test car scored in Tables 1 and 5 (None: all).
    workers : processes for the dataset build and the rig study (results do not depend on it).
    """

    out: Path
    quick: bool = False
    schedule: str = "budget"
    cars_meshes: Path = Path("../shared/data/meshes/apolloscape-cars")
    category_meshes: Path = Path("../shared/data/meshes/categories")
    lidar: Path = Path("../shared/data/lidar")
    cars_data: Path | None = None
    eval_views: int | None = 200
    workers: int = 1
    seed: int = 0
    progress: bool = True

    # --- sizes of the two modes -----------------------------------------------------------
    @property
    def views(self) -> int:
        """Partial observations per car of a dataset we build (the paper: 2000)."""
        return 16 if self.quick else 2000

    @property
    def cars_per_category(self) -> int | None:
        """--quick: cars of each body type in the small dataset (one train, val, test each)."""
        return 3 if self.quick else None

    @property
    def meshes_per_category(self) -> int | None:
        """--quick: meshes per category in the rig study (None: all)."""
        return 2 if self.quick else None

    @property
    def cars_path(self) -> Path:
        return Path(self.cars_data) if self.cars_data is not None else self.out / "data" / "cars.h5"

    @property
    def mode(self) -> str:
        return "quick" if self.quick else "full"
