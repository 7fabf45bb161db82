"""The lab: the experiments that measure the package, kept apart from the product.

``reproduce``: the paper's experiment end to end (``slungload reproduce``) and the training
jobs the studies share; ``study``: the studies of training (``slungload study data|size|loads``,
``slungload tune``); ``control``: the closed-loop experiments in the simulator (``slungload
control``'s comparison, ``study control``, ``study control-loads``, ``record``), the oracle MPC
and the batched plant it flies; ``bench``: the latency and throughput benchmarks and their
tables (``slungload benchmark``).

The product (config ... deploy, and ``control``: the MPC, the geometric controller, closed-loop
flight) imports nothing from here (``tests/test_layout.py``); the command line wires both.
"""
