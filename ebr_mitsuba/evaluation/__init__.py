"""Scoring a trained model (or a baseline) against ground truth: ``ebr eval`` and the benches.

Pipeline order (``docs/conventions.md``, "Pipeline"): after :mod:`ebr_mitsuba.model` — a
:class:`~ebr_mitsuba.model.predictor.Predictor` runs on every sample of a generated data set and
its maps are scored with the metrics of :mod:`ebr_mitsuba.metrics` (per-map RMSE, re-render RMSE,
SSIM).

==============  ===================================================================================
module          contents
==============  ===================================================================================
``evaluate``    a predictor over a data set (:func:`~.evaluate.evaluate`), the sample predictors of a
                model, of ``ebr estimate`` and of the oracle, grouping by material class
``baselines``   what a model must beat: the training set's mean maps, the oracle constant
==============  ===================================================================================

Importing this package imports nothing heavy; ``evaluate`` imports torch.
"""
