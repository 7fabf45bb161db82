"""Model-predictive control of the vehicle and its slung load, flown in the simulator.

``prediction``: prediction models behind one interface (the physics model, any trained network
of ``models.MODELS`` from a run folder); ``mpc``: the sampling (MPPI) controller that meets
``sim.controller.Controller``; ``closed_loop``: guarded flights and their metrics;
``report``: ``slungload control``'s comparison, report.md and figures (docs/control.md).

Like ``training/``, ``evaluation/`` and ``deploy/``, this package imports nothing here: its
modules load torch, MuJoCo and matplotlib.
"""
