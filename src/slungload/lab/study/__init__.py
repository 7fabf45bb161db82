"""The studies of training (``slungload study data|size|loads``, ``slungload tune``), one
module each; what each runs: ``config`` (light: the command line's help reads it).

- ``data``: where physics-informed training helps: RMSE against the number of training
  flights (``study_data``, ``DataStudyConfig``).
- ``size``: how large the network must be for control: validation RMSE against the MPC's
  batched rollout time, per named network size (``study_size``, ``SizeStudyConfig``).
- ``loads``: one model for many loads: the physics-step network trained on one load, on many,
  and adapting to each window's constants estimated in flight, against physics with the
  nominal, estimated and true constants, on unseen loads inside and beyond the training range
  (``study_loads``, ``LoadsStudyConfig``).
- ``tune``: the configuration search (``run_tune``; ``SearchSpace``, ``TuneSettings``).

The names below are resolved on first use (PEP 562), so that the CLI's help reads ``config``
without loading torch.
"""

from __future__ import annotations

from ..._lazy import lazy_exports

_EXPORTS: dict[str, tuple[str, ...]] = {
    "data": ("StudyRow", "study_data", "write_study"),
    "size": ("SizeRow", "SizeStudy", "study_size", "write_size_study"),
    "loads": ("LoadsRow", "study_loads", "write_loads_study"),
    "config": ("DataStudyConfig", "LoadsStudyConfig", "SearchSpace", "SizeStudyConfig",
               "TuneSettings"),
}  # fmt: skip
__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
