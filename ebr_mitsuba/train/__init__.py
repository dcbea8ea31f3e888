"""Training, inference and evaluation of the networks (``ebr train``, ``ebr eval``, ``ebr estimate``).

==============  ===================================================================================
module          contents
==============  ===================================================================================
``config``      typed TOML training config, every default in one place (:func:`load_config`)
``checkpoint``  atomic checkpoints with weights, config, git hash, step, optimizer state, kind;
                :func:`load_checkpoint`, :func:`export_model`
``bundle``      :class:`ModelBundle` (networks + configs + training-data facts)
``data``        the training data set in memory
``cache``       per-sample exemplar selections and extracted SGs on disk (stage 1, stage 2)
``renders``     the cascade's renderers (torch flash + Dr.Jit SG environment through ``dr.wrap``)
``trainer``     the training loop: phases, losses, CSV log, progress, resume
``ddp``         data-parallel training under ``torchrun`` (gloo on CPU)
``inference``   :func:`load_model`, :func:`predict` (photos → maps + SGs), :class:`Prediction`
``metrics``     per-map RMSE, re-render RMSE and SSIM
``baselines``   the mean-maps baseline
``evaluate``    a model or baseline over a data set (``ebr eval``)
==============  ===================================================================================

Importing this package imports nothing heavy; the modules import torch (and Mitsuba when they
render).
"""
