"""The MPC on a real autopilot: PX4 over MAVLink (pymavlink), and its simulated twin.

``bridge`` (``fly``: the MPC flying a PX4 vehicle, its safety in ``safety``, its reference in
``reference``, its log in ``tlog``), ``px4`` (PX4's MAVLink subset and frames), ``config``
(``BridgeConfig``, ``SilConfig``: every default), ``sil`` (the MuJoCo simulator behind a
MAVLink endpoint that answers as PX4 does). Nothing is imported here: the bridge loads
numpy, onnxruntime and pymavlink only, the endpoint MuJoCo too (docs/deployment.md).
"""
