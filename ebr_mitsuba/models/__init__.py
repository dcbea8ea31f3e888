"""Trained models shipped with ebr-mitsuba (package data; see docs/models.md).

``ebrenv_small.pt``: the EBREnv lighting net + cascade of ``configs/train_small.toml`` (NAFNet
``small`` size, 64² grid, float16 weights), loaded by
:func:`ebr_mitsuba.model.predict.load_model` when no checkpoint is given.
``ebrenv_near_far.pt``: the same networks reading the four shots of a near-far capture
(``configs/train_real_near_far.toml``, warm-started from ``ebrenv_small.pt``), used by ``ebr
estimate`` when far shots are given and no checkpoint is (docs/models.md, "Near-far captures").
``dualloss_small.pt``: the five-light dual-loss U-Net of ``configs/dualloss_real.toml``, used by
``ebr estimate --lights`` (docs/fivelight.md).
``mair_small.pt``: the multi-view MAIR model of ``configs/mair_small.toml`` (``small`` preset, 32²
grid), used by ``ebr estimate --views`` (docs/mair_eval.md).
"""
