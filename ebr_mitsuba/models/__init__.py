"""Trained models shipped with ebr-mitsuba (package data; see docs/models.md).

``ebrenv_small.pt``: the EBREnv lighting net + cascade of ``configs/train_small.toml`` (NAFNet
``small`` size, 64² grid, float16 weights), loaded by
:func:`ebr_mitsuba.model.predict.load_model` when no checkpoint is given.
"""
