"""Drawing: static pictures (matplotlib, PNG) and the interactive viewer (plotly, one HTML page).

Layering: this package draws arrays; it imports :mod:`spotlights.geometry` and
:mod:`spotlights.data` only (never learning, experiments or the CLI). Pictures are drawn on
:class:`matplotlib.figure.Figure` objects rendered by Agg: no pyplot state, no global
backend, so importing or calling it never changes the caller's matplotlib set-up.
matplotlib and plotly are imported when a function needs them.

Modules by topic:

- :mod:`.points` point sets (:class:`Layer`, :func:`render_layers`)
- :mod:`.mesh` meshes, z-buffered (:func:`render_mesh`; the rasteriser is :mod:`.raster`)
- :mod:`.encoding` Spotlights encodings (:func:`render_encoding`, :func:`viewpoint_rays`)
- :mod:`.sample` dataset samples (:func:`render_sample`)
- :mod:`.scene` whole scans with boxes (:func:`render_scene`, :func:`render_frame`)
- :mod:`.bev` a frame's bird's-eye raster (numpy and PIL, no matplotlib: :func:`~spotlights.viz.bev.bev_png`)
- :mod:`.completion` predictions beside their ground truth (:func:`render_predictions`)
- :mod:`.grid`, :mod:`.study`, :mod:`.density` the reproduction's, rig study's and density analysis' figures
- :mod:`.html` the interactive viewer (:func:`write_html`, ``spotlights view``)
"""

from ._figure import png_bytes, write_png
from .completion import render_predictions
from .encoding import render_encoding, viewpoint_rays
from .grid import render_cloud_grid, render_rig_rays
from .mesh import render_mesh
from .points import DEFAULT_VIEWS, Layer, render_layers
from .sample import render_sample
from .scene import SceneObject, render_frame, render_scene, scene_png
from .study import plot_rig_study

__all__ = [
    "DEFAULT_VIEWS",
    "Layer",
    "SceneObject",
    "plot_rig_study",
    "png_bytes",
    "render_cloud_grid",
    "render_encoding",
    "render_frame",
    "render_layers",
    "render_mesh",
    "render_predictions",
    "render_rig_rays",
    "render_sample",
    "render_scene",
    "scene_png",
    "viewpoint_rays",
    "write_png",
]
