"""What a reproduction computes: its settings and the runs, rigs and ray counts of the tables."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path


@dataclass(frozen=True)
class RunSpec:
    """One training run of a reproduction.

    model : registry name (``sanet``, ``sanet-hit``, ``pcn``...).
    rig : the dataset rig its depths regress (None: the file's default rig, cap-32x64-60).
    config : a packaged config YAML applied after the schedule (``spotlights train --config``), as a path
        relative to ``spotlights/learning/configs`` (e.g. ``variants/sanet-hit-dense.yaml``); None: none.
    """

    model: str
    rig: str | None = None
    config: str | None = None

    @property
    def config_path(self) -> Path | None:
        """The absolute path of :attr:`config` inside the installed package (None without a config)."""
        if self.config is None:
            return None
        return Path(str(resources.files("spotlights.learning") / "configs" / self.config))


# Table 1 runs in the paper's row order, and every run: name -> RunSpec(model, rig, config).
TABLE1_RUNS = ("atlasnet", "pcn", "foldingnet", "topnet", "sanet")
TABLE5_RUNS = {"32x64": "sanet", "64x32": "sanet-64x32", "256x64": "sanet-256x64"}
BOX_RIG = "box-32x64-ellipsoid-s1"
"""The box-targeted rig of the box table (docs/box-rig.md): ``--rig-kind box`` at 2048 rays, the default box rig."""
DENSE_RIG = "box-128x128-ellipsoid-s1"
"""The dense box-targeted rig (16,384 rays) of the default model (``variants/sanet-hit-dense.yaml``)."""
DENSE_CONFIG = "variants/sanet-hit-dense.yaml"
"""The packaged config of the default model: decoder hidden [256, 64], rig box-128x128, 700 steps per epoch."""
RUNS = {
    "sanet": RunSpec("sanet"),
    "pcn": RunSpec("pcn"),
    "foldingnet": RunSpec("foldingnet"),
    "topnet": RunSpec("topnet"),
    "atlasnet": RunSpec("atlasnet"),
    "sanet-64x32": RunSpec("sanet", "cap-64x32-60"),
    "sanet-256x64": RunSpec("sanet", "cap-256x64-60"),
    "sanet-box": RunSpec("sanet", BOX_RIG),
    "sanet-hit-box": RunSpec("sanet-hit", BOX_RIG),
    "sanet-hit-dense": RunSpec("sanet-hit", DENSE_RIG, DENSE_CONFIG),
    "snowflakenet": RunSpec("snowflakenet"),
}
PRODUCT_RUNS = ("sanet-hit-box", "sanet-hit-dense")
"""The product's models beside the paper's in Tables 1 and 2: the hit-aware SA-Net on the box rig (2,048 rays)
and the default model (the hit-aware SA-Net on the dense box rig, 16,384 rays)."""
PEER_RUNS = ("snowflakenet",)
"""The modern peer beside the paper's models in Table 1 (SnowflakeNet, 16,384 points): trained and scored like them,
no paper values, not part of the SA-Net claims."""
DEFAULT_RUN = "sanet-hit-dense"
"""The run of the package's default model."""
BASELINE_RUNS = ("atlasnet", "pcn", "foldingnet", "topnet")
"""The paper's baselines (Tables 1 and 2)."""
TABLE2_SETS = {"av2": "Argoverse 2", "nuscenes": "nuScenes"}
"""The real sets of Table 2 (extraction step ``real-<set>``, consistency step ``consistency-<set>``) and their names."""
TABLE2_CLASSES = ("car", "truck", "trailer")
"""Classes extracted and scored in Table 2: the paper's KITTI-360 classes without caravan (neither AV2 nor nuScenes has it)."""
TABLE2_RUNS = TABLE1_RUNS + PRODUCT_RUNS
"""The checkpoints scored in Table 2 (report rows named after the runs)."""
RIG_STEPS = {BOX_RIG: "cars-data-box", DENSE_RIG: "cars-data-dense"}
"""Rigs a car dataset may lack -> the step that adds them (``dataset add-rig``); runs on them need that step."""
BOX_RUNS = {"paper": "sanet", "box": "sanet-box"}  # the box table's SA-Net pair: paper rig (Table 1 run) vs box rig
DISPLAY = {
    "sanet": "SA-Net",
    "sanet-box": "SA-Net (box rig)",
    "sanet-hit-box": "SA-Net hit-aware (box, 2,048 rays)",
    "sanet-hit-dense": "SA-Net hit-aware (box, 16,384 rays; default)",
    "pcn": "PCN",
    "foldingnet": "FoldingNet",
    "topnet": "TopNet",
    "atlasnet": "AtlasNet",
    "snowflakenet": "SnowflakeNet (modern peer, 16,384 points)",
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
    def real_frames(self) -> int | None:
        """--quick: frames of each Table 2 set extracted (the first ones, in time order; None: all)."""
        return 2 if self.quick else None

    @property
    def real_min_points(self) -> int | None:
        """--quick: points an object of a Table 2 set needs to be extracted (None: the extraction's default, 10)."""
        return 50 if self.quick else None

    @property
    def cars_path(self) -> Path:
        return Path(self.cars_data) if self.cars_data is not None else self.out / "data" / "cars.h5"

    @property
    def mode(self) -> str:
        return "quick" if self.quick else "full"
