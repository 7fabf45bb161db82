"""Model-predictive control of the vehicle and its slung load, flown in the simulator.

``history``: the measured states and applied inputs the controller keeps for its prediction
model (``models.prediction``: the physics model or any trained network of ``models.MODELS``,
through ``predict_candidates``); ``mpc``: the sampling (MPPI) controller that meets
``sim.controller.Controller``; ``closed_loop``: guarded flights and their metrics;
``report``: ``slungload control``'s comparison, report.md and figures (docs/control.md).

Like ``training/``, ``evaluation/`` and ``deploy/``, this package imports nothing here: its
modules load torch, MuJoCo and matplotlib.
"""
