"""Model-predictive control of the vehicle and its slung load, in the simulator and onboard.

``mppi``: the sampling (MPPI) controller written once in numpy, ``MPPIController.step(state,
reference) -> Command``, the API a vehicle's own loop calls (numpy only; ``from_onnx`` runs it
over an exported network on ONNX Runtime, ``deploy.onboard``); ``history``: the measured states
and applied inputs it keeps for its prediction model (numpy); ``mpc``: ``SamplingMPC``, the same
controller over any torch prediction model (``models.prediction``: the physics model or any
trained network of ``models.MODELS``, through ``predict_candidates``), meeting
``sim.controller.Controller``; ``closed_loop``: guarded flights and their metrics;
``comparison``: ``slungload control``'s flights (``compare``), ``results`` their statistics,
``report`` their report.md and figures (docs/control.md).

Like ``training/``, ``evaluation/`` and ``deploy/``, this package imports nothing here: ``mpc``,
``closed_loop``, ``comparison`` and ``report`` load torch, MuJoCo and matplotlib, and the
onboard controller must not.
"""
