"""The model at inference: loading, prediction, the cascade's renders and checkpoints.

Pipeline order (``docs/conventions.md``, "Pipeline"): capture → :mod:`ebr_mitsuba.estimate.inputs`
→ **this package** (lighting net → SG extraction → exemplar selection → cascade) →
:mod:`ebr_mitsuba.estimate.refine` → :mod:`ebr_mitsuba.estimate.outputs`. Training
(:mod:`ebr_mitsuba.train`) builds and saves the same :class:`~.bundle.ModelBundle`.

==============  ===================================================================================
module          contents
==============  ===================================================================================
``predictor``   the :class:`~.predictor.Predictor` protocols that ``ebr estimate``, ``ebr eval``,
                the benches and the trainer's cache take, and their results (``Prediction``,
                ``Lighting``, ``PassInputs``); numpy only
``predict``     :func:`~.predict.load_model`, :func:`~.predict.load_predictor`,
                :class:`~.predict.ModelPredictor`, :func:`~.predict.predict` (photos → maps + SGs)
``bundle``      :class:`~.bundle.ModelBundle` (networks + configs + training-data facts)
``config``      :class:`~.config.TrainConfig`, the typed TOML config a model is trained from and
                carries in its checkpoint (:func:`~.config.load_config`, :func:`~.config.config_from_dict`)
``checkpoint``  atomic checkpoints with weights, config, git hash, step, optimizer state, kind;
                :func:`~.checkpoint.load_checkpoint`, :func:`~.checkpoint.export_model`
``renders``     the cascade's renderers (torch flash + Dr.Jit SG environment through ``dr.wrap``),
                the same in training and at inference
``device``      :func:`~.device.pick_device`
==============  ===================================================================================

The shipped weights are package data of :mod:`ebr_mitsuba.models`. Importing this package imports
nothing heavy; the modules but ``predictor`` import torch (and Mitsuba when they render).
"""
