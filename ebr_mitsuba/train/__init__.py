"""Training of the networks (``ebr train``).

The model it trains (networks, checkpoints, the cascade's renders, prediction) and the training
config the model carries (:mod:`ebr_mitsuba.model.config`) live in :mod:`ebr_mitsuba.model`.

==============  ===================================================================================
module          contents
==============  ===================================================================================
``data``        the training data set in memory
``cache``       per-sample exemplar selections and extracted SGs on disk (stage 1, stage 2)
``phases``      the training phases (lighting, diffuse, specular, refinement, finetune, dualloss;
                MAIR's normal, lighting, brdf)
``trainer``     the training loop: phases, losses, CSV log, progress, resume
``ddp``         data-parallel training under ``torchrun`` (gloo on CPU)
==============  ===================================================================================

Scoring a trained model (``ebr eval``, the benches) is :mod:`ebr_mitsuba.evaluation`.

Importing this package imports nothing heavy; the modules import torch (and Mitsuba when they
render).
"""
