"""Train one loss variant of the registered 'physics-step' network and evaluate it.

The architecture lives in the package (``models.physics_step.PhysicsStepNet``, picked by
``ModelConfig.architecture``); this replaces the session-3 prototype
(``experiments/physics_base_prototype.py`` at commit 06917c2, which patched
``SlungLoadNet.forward``; its numbers are in docs/BENCHMARKS.md). Default preset without the
time cap, as the prototype ran; the same as ``slungload train --model physics-step``.

    python experiments/physics_step_run.py DATA_DIR VARIANT OUT_DIR [SEED]
"""

from __future__ import annotations

import sys
from pathlib import Path

from slungload.config import ModelConfig
from slungload.evaluation.evaluator import evaluate
from slungload.training.trainer import train


def main(data: str, variant: str, out: str, seed: int = 0) -> None:
    config = ModelConfig(architecture="physics-step")  # train() sets slack for the variant
    run = train(
        data, out=out, variant=variant, seed=seed, model_config=config, time_cap=False,
        progress=False,
    )  # fmt: skip
    print(run.epochs, run.stop_reason, f"{run.seconds:.0f} s", flush=True)
    evaluate([out], out=f"{out}_eval", progress=False)
    print(Path(f"{out}_eval/rmse.csv").read_text())


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3], *map(int, sys.argv[4:5]))
