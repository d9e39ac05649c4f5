"""Files shipped inside the package (CC0 demo assets); see README.md here."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def asset_path(name: str) -> Path:
    """Filesystem path of a bundled asset, e.g. ``asset_path("kenney-sedan.glb")``."""
    p = Path(str(resources.files(__package__) / name))
    if not p.exists():
        raise FileNotFoundError(f"bundled asset {name!r} is missing from the installation")
    return p


# (file, up axis, forward axis) of the bundled demo vehicle.
DEMO_VEHICLE = ("kenney-sedan.glb", "y", "z")
