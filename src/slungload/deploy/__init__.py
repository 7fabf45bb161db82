"""Deployment: the numpy ``Predictor`` facade (``predictor``), ONNX export and runtime
(``onnx``), the Numba code (``compiled``: ``CompiledPredictor`` and the MPC's compiled
backend), the one batch-1 timing loop (``timing``) and ``benchmark`` (``benchmarks``). Nothing
is imported here, so each path loads only its own runtime (ONNX Runtime, Numba).
"""
