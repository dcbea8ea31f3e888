"""Trained models shipped with ebr-mitsuba (package data; see docs/models.md).

``ebrenv_real.pt``: the EBREnv lighting net (NAFNet ``small``) + cascade (NAFNet ``medium``, the
size the curve of ``ebr bench sizes`` picks), trained on the real texture sets and HDR maps by
the progressive recipe: ``configs/train_real.toml`` at 128², then ``configs/train_real_256.toml``
at 256² (256² grid since 2026-12-05, float16 weights; its checkpoint's ``lineage`` names the
phases), loaded by :func:`ebr_mitsuba.model.predict.load_model` when no checkpoint is given. The
128² model it continues is ``git show 29ffed6:ebr_mitsuba/models/ebrenv_real.pt``. It replaced
``ebrenv_small.pt`` (``configs/train_small.toml``, procedural data, 64²) on 2026-12-04; that file is
in the git history (``git show 93c04ca:ebr_mitsuba/models/ebrenv_small.pt``).
``ebrenv_near_far.pt``: the previous model's networks reading the four shots of a near-far capture
(``configs/train_real_near_far.toml``, warm-started from ``ebrenv_small.pt``), used by ``ebr
estimate`` when far shots are given and no checkpoint is (docs/models.md, "Near-far captures").
``dualloss_small.pt``: the five-light dual-loss U-Net of ``configs/dualloss_real.toml``, used by
``ebr estimate --lights`` (docs/fivelight.md).
``mair_small.pt``: the multi-view MAIR model of ``configs/mair_small.toml`` (``small`` preset, 32²
grid), used by ``ebr estimate --views`` (docs/mair_eval.md).
"""
