"""The product: complete the vehicles of LiDAR frames from their boxes.

==========================  =====================================================================
module                      job
==========================  =====================================================================
:mod:`.frame`               one frame: a scan and its boxes -> every vehicle completed
                            (:func:`~.frame.complete_scene`, :class:`~.frame.SceneConfig`,
                            :class:`~.frame.SceneResult`, :class:`~.frame.ObjectResult`)
:mod:`.scan`                one scan from files (what ``spotlights complete`` runs): options, checks, outputs
:mod:`.frames`              every frame of a dataset into a folder, resumable (``spotlights real complete``)
:mod:`.fusion`              fusion and box refinement over tracks (``real complete --fuse``)
:mod:`.names`               output file names of frames, sequences and tracks
:mod:`.demo`                the end-to-end demonstration (``spotlights demo``)
==========================  =====================================================================

Layer: above :mod:`spotlights.learning` (models) and below :mod:`spotlights.experiments` (the paper's
studies) and the command line (docs/architecture.md).
"""
