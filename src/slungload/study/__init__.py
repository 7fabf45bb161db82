"""Studies beyond the paper (``slungload study``), one module each.

- ``data``: where physics-informed training helps: RMSE against the number of training
  flights (``study_data``).
- ``size``: how large the network must be for control: validation RMSE against the MPC's
  batched rollout time, per named network size (``study_size``).
"""

from __future__ import annotations

from .data import StudyRow, study_data, write_study
from .size import SizeRow, SizeStudy, study_size, write_size_study

__all__ = [
    "SizeRow",
    "SizeStudy",
    "StudyRow",
    "study_data",
    "study_size",
    "write_size_study",
    "write_study",
]
