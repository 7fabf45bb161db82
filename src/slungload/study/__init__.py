"""Studies beyond the paper (``slungload study``), one module each.

- ``data``: where physics-informed training helps: RMSE against the number of training
  flights (``study_data``).
- ``size``: how large the network must be for control: validation RMSE against the MPC's
  batched rollout time, per named network size (``study_size``).
- ``loads``: one model for many loads: the physics-step network trained on one load, on many,
  and adapting to each window's constants estimated in flight, against physics with the
  nominal, estimated and true constants, on unseen loads inside and beyond the training range
  (``study_loads``; what it flies: ``loads_config.LoadsStudyConfig``).

The names below are resolved on first use (PEP 562), so that the CLI's help reads
``loads_config`` without loading torch.
"""

from __future__ import annotations

from .._lazy import lazy_exports

_EXPORTS: dict[str, tuple[str, ...]] = {
    "data": ("StudyRow", "study_data", "write_study"),
    "size": ("SizeRow", "SizeStudy", "study_size", "write_size_study"),
    "loads": ("LoadsRow", "study_loads", "write_loads_study"),
    "loads_config": ("LoadsStudyConfig",),
}
__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
