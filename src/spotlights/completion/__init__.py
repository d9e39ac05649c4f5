"""The product: complete the vehicles of LiDAR frames from their boxes.

==========================  =====================================================================
module                      job
==========================  =====================================================================
:mod:`.scene_config`        :class:`~.scene_config.SceneConfig`: the options of a frame's completion
:mod:`.frame`               one frame: a scan and its boxes -> every vehicle completed
                            (:func:`~.frame.complete_scene`: cropping, batching, the heading check)
:mod:`.results`             :class:`~.results.ObjectResult`, :class:`~.results.SceneResult` (``save``)
:mod:`.writing`             a frame's files: the scene PLY, per-object PLYs, the JSON summary
:mod:`.pictures`            a frame drawn: the bird's-eye raster, close-ups where asked, the HTML page
:mod:`.detections`          a detector's boxes tracked into the frames of ``real complete``
:mod:`.scan`                one scan from files (what ``spotlights complete`` runs): options, checks, outputs
:mod:`.frames`              every frame of a dataset into a folder, resumable (``spotlights real complete``)
:mod:`.frame_selection`     that run's settings, its frames and their file names, what marks a frame done
:mod:`.picture_processes`   its frame pictures, drawn by worker processes beside the loop
:mod:`.shapes`              one shape per track (``--track-shape``)
:mod:`.fusion`              fusion and box refinement over tracks (``real complete --fuse``)
:mod:`.track_windows`       each frame's fusion window of every track (the work of the fusion)
:mod:`.track_worker`        that work in a worker process beside the frame loop
:mod:`.names`               output file names of frames, sequences and tracks
:mod:`.demo`                the end-to-end demonstration (``spotlights demo``)
==========================  =====================================================================

Layer: above :mod:`spotlights.learning` (models) and below :mod:`spotlights.experiments` (the paper's
studies) and the command line (docs/architecture.md).
"""
