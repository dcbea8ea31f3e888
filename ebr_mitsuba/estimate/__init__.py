"""``ebr estimate``: SVBRDF maps and SG lighting from real or synthetic flash/no-flash photos.

=============  ===================================================================================
module         contents
=============  ===================================================================================
``inputs``     reading the shots, EXIF exposure matching, the input checks (:class:`Inputs`)
``resample``   the working-size policy (minimum, model grid, ``--max-size``)
``fullres``    the maps at full resolution from the capture's lighting (one pass or tiles, the
               scale ensemble, true per-pixel geometry)
``fastnet``    a channels-last inference forward of the NAFNets; multiply-add counting
``tiling``     tile origins, raised-cosine blending weights, bilinear upsampling
``refine``     test-time refinement of maps (and lobes) with the differentiable renderer
``metrics``    per-map RMSE against ground truth
``outputs``    the files of an estimate directory (maps, env pictures, re-renders, residuals, ...)
``report``     the self-contained ``report.html``
``pipeline``   the estimate job: stages, timings, the summary (:func:`run_estimate`)
``fivelight``  the five-light estimate (``--lights``): five known point lights, a dual-loss model
``gallery``    flash-only estimates of a photo folder as a docs page
=============  ===================================================================================

Pipeline order: capture → ``inputs`` (and ``resample``) → the model (:mod:`ebr_mitsuba.model`, a
:class:`~ebr_mitsuba.model.predictor.Predictor` that :func:`~.pipeline.run_estimate` takes as an
argument; ``fullres`` runs its cascade above the grid) → ``refine`` → ``outputs`` and ``report``.
Importing this package imports neither torch nor Mitsuba.
"""
