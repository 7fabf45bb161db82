"""The state and input layout: the only place that knows which column is what (no torch).

State ``x`` (13 numbers, the paper's x_k)::

    p   [0:3]    vehicle position, world frame, m
    v   [3:6]    vehicle velocity, world frame, m/s
    q   [6:10]   vehicle attitude, unit quaternion **w-x-y-z**, body -> world
    pL  [10:13]  load position, world frame, m

Input ``u`` (4 numbers, the paper's u_k)::

    T      [0:1]  total thrust, N (the commanded value in the data files)
    omega  [1:4]  body angular rates, body frame, rad/s

Auxiliary load state ``a`` (6 numbers, not measured, estimated from data; see ``load_state``)::

    vL       [0:3]  load velocity, world frame, m/s
    OmegaL   [3:6]  load angular velocity about the vehicle, world frame, rad/s

The data files, the ``deploy.Predictor`` facade and its exports store quaternions **x-y-z-w**
(like roma): ``STATE_COLUMNS`` names the 13 state columns in that order, ``HISTORY_COLUMNS``
the 17 columns of a history row (x_k then u_k), and ``WXYZ_TO_XYZW`` picks the package's
quaternion components in file order. World frame is z up.

Importable with numpy alone (no torch, no roma), for code that must run without them (an
onboard controller); ``state`` re-exports these names beside its torch helpers.
"""

from __future__ import annotations

from typing import TypeVar

A = TypeVar("A")  # a numpy array or a torch tensor

STATE_DIM = 13
INPUT_DIM = 4
AUX_DIM = 6
HISTORY_DIM = STATE_DIM + INPUT_DIM  # 17 columns of a facade history row: x_k then u_k

# State slices.
POS = slice(0, 3)
VEL = slice(3, 6)
QUAT = slice(6, 10)
LOAD_POS = slice(10, 13)
# Input slices.
THRUST = slice(0, 1)
RATES = slice(1, 4)
# Auxiliary load-state slices.
LOAD_VEL = slice(0, 3)
LOAD_RATE = slice(3, 6)

# Named groups used by the loss, metrics and plots, in the paper's order.
GROUPS: dict[str, slice] = {
    "position": POS,
    "velocity": VEL,
    "quaternion": QUAT,
    "load_position": LOAD_POS,
}
GROUP_UNITS = {"position": "m", "velocity": "m/s", "quaternion": "-", "load_position": "m"}
STATE_NAMES = (
    "px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "pLx", "pLy", "pLz",
)  # fmt: skip
INPUT_NAMES = ("T", "wx", "wy", "wz")


def split_state(x: A) -> tuple[A, A, A, A]:
    """(..., 13) -> p (..., 3), v (..., 3), q (..., 4) w-x-y-z, pL (..., 3): views of the
    columns of a numpy array or a torch tensor."""
    return x[..., POS], x[..., VEL], x[..., QUAT], x[..., LOAD_POS]


# --- the file layout (quaternion x-y-z-w) ---------------------------------------------------

WXYZ_TO_XYZW = (1, 2, 3, 0)  # file order of the package's quaternion components
XYZW_TO_WXYZ = (3, 0, 1, 2)  # package order of the file's quaternion components
# Column names of the file layout: the 13 states (quaternion x-y-z-w) then the 4 inputs.
STATE_COLUMNS: tuple[str, ...] = (
    STATE_NAMES[: QUAT.start]
    + tuple(STATE_NAMES[QUAT.start + i] for i in WXYZ_TO_XYZW)
    + STATE_NAMES[QUAT.stop :]
)
HISTORY_COLUMNS: tuple[str, ...] = STATE_COLUMNS + INPUT_NAMES
