"""Control of the vehicle and its slung load: the controllers a user flies, in the simulator
and onboard.

``controllers``: the simulator's controllers by name (the PID, the geometric controller, the
MPC), the one table every closed-loop experiment builds from; ``mppi``: the sampling (MPPI)
controller written once in numpy, ``MPPIController.step(state, reference) -> Command``, the API
a vehicle's own loop calls (numpy only; ``from_file`` runs it over an exported network on ONNX
Runtime, ``deploy.onboard``); ``history``: the measured states and applied inputs it keeps for
its prediction model (numpy); ``mpc``: ``SamplingMPC``, the same controller over any torch
prediction model (``models.prediction.PredictionModel``: the physics model or any trained
network of ``models.MODELS``), meeting ``sim.controller.Controller``; ``geometric``: the
payload-aware geometric controller; ``closed_loop``: guarded flights and their metrics. The
experiments that fly them (``slungload control``, the studies, the oracle) are the lab's
(``lab.control``; docs/control.md).

Like ``training/``, ``evaluation/`` and ``deploy/``, this package imports nothing here: ``mpc``
and ``closed_loop`` load torch and MuJoCo, and the onboard controller must not.
"""
