"""Training and evaluation of the networks (``ebr train``, ``ebr eval``).

The model they train and score (networks, checkpoints, the cascade's renders, prediction) lives in
:mod:`ebr_mitsuba.model`.

==============  ===================================================================================
module          contents
==============  ===================================================================================
``config``      typed TOML training config, every default in one place (:func:`load_config`)
``data``        the training data set in memory
``cache``       per-sample exemplar selections and extracted SGs on disk (stage 1, stage 2)
``phases``      the training phases (lighting, diffuse, specular, refinement, finetune, dualloss)
``trainer``     the training loop: phases, losses, CSV log, progress, resume
``ddp``         data-parallel training under ``torchrun`` (gloo on CPU)
``metrics``     per-map RMSE, re-render RMSE and SSIM
``baselines``   the mean-maps baseline
``evaluate``    a model or baseline over a data set (``ebr eval``)
==============  ===================================================================================

Importing this package imports nothing heavy; the modules import torch (and Mitsuba when they
render).
"""
