"""The model registry: a model's name -> ``"module:Class"``, its display name, and the class.

The lowest module of ``learning`` beside the errors: the config schema
(:mod:`spotlights.learning.config`) checks ``model.args`` against the class, and the
configurations (:mod:`spotlights.learning.models`) are merged from the packaged YAML of each name.
Importing it imports no model (and no torch); :func:`model_class` imports the one asked for.
"""

from __future__ import annotations

import importlib

from ..errors import ParameterError

MODEL_REGISTRY: dict[str, str] = {
    "sanet": "spotlights.learning.models.sanet:SANet",
    "sanet-hit": "spotlights.learning.models.sanet_hit:HitSANet",
    "sanet-local": "spotlights.learning.models.sanet_local:LocalSANet",
    "pcn": "spotlights.learning.models.pcn:PCN",
    "foldingnet": "spotlights.learning.models.foldingnet:FoldingNet",
    "topnet": "spotlights.learning.models.topnet:TopNet",
    "atlasnet": "spotlights.learning.models.atlasnet:AtlasNet",
    "snowflakenet": "spotlights.learning.models.snowflakenet:SnowflakeNet",
}
MODEL_NAMES = tuple(MODEL_REGISTRY)
SCHEDULE_FALLBACK = {"sanet-hit": "sanet", "sanet-local": "sanet-hit"}
"""A schedule without a section for a model uses the section of the model named here (a variant trains
like its parent unless the schedule says otherwise)."""
DISPLAY_NAMES = {
    "sanet": "SA-Net",
    "sanet-hit": "SA-Net (hit-aware)",
    "sanet-local": "SA-Net (ray-local)",
    "pcn": "PCN",
    "foldingnet": "FoldingNet",
    "topnet": "TopNet",
    "atlasnet": "AtlasNet",
    "snowflakenet": "SnowflakeNet",
}


def check_model_name(name: str) -> str:
    """Return ``name`` if registered, else raise :class:`ParameterError` listing the known names."""
    if name not in MODEL_REGISTRY:
        raise ParameterError(f"unknown model {name!r}; known models: {', '.join(MODEL_NAMES)}")
    return name


def model_class(name: str):
    """The model class registered under ``name`` (imports its module, and torch, now)."""
    module, cls = MODEL_REGISTRY[check_model_name(name)].split(":")
    return getattr(importlib.import_module(module), cls)
