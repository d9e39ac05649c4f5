"""Learning layer: SA-Net and the four point-cloud baselines, losses, training, evaluation.

Nothing heavy is imported here (the metrics are numpy-only, one layer down in
``spotlights.metrics``); torch is imported by the modules that
need it (``models``, ``losses``, ``data``, ``train``, ``evaluate``, ``inference``).

Main entry points::

    from spotlights.learning.models import build_model, load_config, MODEL_NAMES
    from spotlights.learning.train import train
    from spotlights.learning.evaluate import evaluate_checkpoints
    from spotlights.learning.inference import load_completer
"""
