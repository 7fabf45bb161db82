"""Evaluation against the test flights: ``predictors`` (physics-only and network, batched),
``metrics`` (the paper's errors, MAE curves, RMSE), ``results`` (the typed ``Report`` and the
paper's numbers, once), ``evaluator`` (``evaluate``), ``report`` and ``plots`` (files), and
``machine`` (what a measurement ran on). Nothing is imported here: see ``slungload``'s API.
"""
