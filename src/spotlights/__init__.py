"""spotlights: the Spotlights shape representation (Wei et al.) as a library.

Layers (imports point down only)::

    cli -> experiments -> learning -> data -> geometry <- analysis

``spotlights.geometry`` (rig, normalisation, ray casting, encoding, I/O) needs
only numpy/scipy/trimesh/embreex; torch is imported only by ``spotlights.learning``.
"""

from ._version import __version__

__all__ = ["__version__"]
