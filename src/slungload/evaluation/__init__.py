"""Evaluation against the test flights of prediction models (``models.prediction``: the
physics model and trained networks, through ``predict_windows``): ``metrics`` (the paper's
errors, MAE curves, RMSE), ``results`` (the typed ``Report`` and the paper's numbers, once),
``evaluator`` (``evaluate``), ``report`` and ``plots`` (files; their tables, figure files,
colours and machine stamp come from ``slungload.reporting``); ``preflight`` (``slungload check``)
and ``verdicts`` (its verdicts beside a run, json only); ``predictors`` holds only deprecated
names. Nothing is imported here: see ``slungload``'s API.
"""
