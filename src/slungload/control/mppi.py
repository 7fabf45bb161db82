"""The MPPI controller, written once in numpy (float64): the API a vehicle's own loop calls.

    controller = MPPIController(model, limits, MPCConfig(samples=256), params)
    for each measurement (every h = 0.03 s, the data rate):
        command = controller.step(state, ReferenceAhead(position, velocity, yaw))
        send command.thrust (N) and command.rates (rad/s, FLU body frame) to the autopilot

``state`` is the measured x_k in the package's layout (``layout.py``: p m, v m/s, q w-x-y-z
body -> world, pL m; world z up); the reference holds the N steps ahead, x_{k+1} ... x_{k+N}
(positions (N, 3) m, velocities (N, 3) m/s, yaw (N,) rad). The controller keeps the history
its model needs (``history.History``). ``model`` is any ``CandidateModel``: numpy in, numpy
out, ``predict_candidates(x_hist (M, 13), u_past (M-1, 4), plans (K, N, 4)) -> (K, N, 13)``;
onboard the exported network on ONNX Runtime (``deploy.onboard.OnnxCandidateModel``), in the
simulator any ``models.prediction.PredictionModel`` through ``mpc.candidate_model`` (the
compiled backends' own numpy entry, or ``mpc.TorchCandidates``).
From PX4's NED/FRD, convert with ``frames`` first (docs/control.md).

At every step the controller

1. appends x_k to its history (and, with ``MPCConfig.constants = "window"``, re-estimates the
   load's cable length and mass from it for the cost: a load it was not told of);
2. samples K input sequences u_k ... u_{k+N-1} around its nominal plan (the previous plan
   shifted by one step, its last row repeated): smooth noise (``MPCConfig.knots`` Gaussian
   control points per channel from numpy's ``Generator``, linearly interpolated over the
   horizon), **clamped to the thrust and body-rate limits**, so every sample, and every
   convex combination of samples, is within them by construction; sample 0 is the plan;
3. predicts their N-step outcomes with its model;
4. scores them (``trajectory_cost``): vehicle position and velocity against the reference,
   load position against its reference (vehicle reference minus l e3), load swing (horizontal
   cable offset; with ``MPCConfig.cost`` "payload" the targets follow the cable direction the
   load's path needs, ``payload_first``), yaw, tilt beyond ``max_tilt``, swing angle beyond
   ``max_swing``, height below ``min_height``, input effort and rate (position errors beyond
   ``position_huber`` growing linearly);
5. weights them by ``exp(-(c - c_min) / lambda)`` with lambda = ``temperature`` times the
   spread ``mean(c) - c_min`` (a scale-free temperature) and applies the first input of the
   weighted plan (receding horizon).

Safe by construction: samples whose prediction is NaN or infinite are dropped; when none is
left, the model raises, or the weighted plan is non-finite or outside the limits, the step
falls back to the last safe plan (shifted), and after ``max_fallback_steps`` consecutive
fallbacks to a hover command (hover thrust, body rates that level the vehicle at the
reference's yaw). An in-flight estimate of the constants that is not finite (a NaN in the
history) is not used: the last good constants stay. Every event is counted in ``MPCStats``.
numpy only (no torch): a test imports this module in a fresh interpreter and checks.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from .. import frames
from ..config import NETWORK_CONSTANTS, VehicleParams
from ..input_lag import NO_LAG, check_lag
from ..layout import INPUT_DIM, QUAT, STATE_DIM
from .contract import CandidateModel, ConstantsEstimate, check_members, has_members, priced
from .cost import (
    COSTS,
    ReferenceAhead,
    VehicleTarget,
    cost_target,
    jumps,
    lean_rows,
    payload_first,
    reference_ahead,
    shape_of,
    tilt_of,
    trajectory_cost,
    yaw_of,
)
from .history import History
from .lagged import with_input_lag
from .limits import InputLimits
from .split import ALL, MEMBER_USES, SPLIT, SplitMembers
from .tracked import TrackedMembers, calibration_of

__all__ = [
    "COSTS",
    "CandidateModel",
    "Command",
    "ConstantsEstimate",
    "InputLimits",
    "MEMBER_USES",
    "MPCConfig",
    "MPCStats",
    "MPPIController",
    "ReferenceAhead",
    "VehicleTarget",
    "check_members",
    "has_members",
    "knots_for",
    "mppi_weights",
    "payload_first",
    "reference_ahead",
    "tilt_of",
    "trajectory_cost",
    "yaw_of",
]


@dataclass(frozen=True)
class MPCConfig:
    """The sampler, the cost weights (per step, SI units squared) and the safety settings."""

    samples: int = 32  # K
    horizon: int = 15  # N, steps of h (0.45 s)
    knots: int = 5  # noise control points per channel over the horizon
    thrust_std: float = 1.0  # N, sampling noise
    rate_std: tuple[float, float, float] = (0.5, 0.5, 0.2)  # rad/s, sampling noise x y z
    temperature: float = 0.3  # lambda / (mean(c) - min(c))
    w_position: float = 20.0  # 1/m^2, vehicle position error
    w_velocity: float = 1.0  # s^2/m^2, vehicle velocity error
    w_load: float = 10.0  # 1/m^2, load position error (reference: vehicle reference - l e3)
    w_swing: float = 10.0  # 1/m^2, horizontal offset of the load from the vehicle
    w_yaw: float = 2.0  # 1/rad^2
    w_tilt: float = 200.0  # 1/rad^2, tilt beyond max_tilt
    max_tilt: float = 0.75  # rad, as the PID's tilt limit
    w_swing_bound: float = 200.0  # 1/rad^2, swing angle beyond max_swing
    max_swing: float = math.inf  # rad, angle of the cable from the vertical (inf: no bound)
    # m: vehicle and load position errors beyond it cost linearly (Huber), so that a far
    # reference (a position step) pulls at a bounded rate instead of the square of the distance
    position_huber: float = math.inf
    # m: vehicle height below it costs w_floor per m^2 per step (-inf: no floor). The arena ends
    # a flight with the vehicle below 0.75 m (the hanging load at the floor); a swing the MPC
    # cannot stop within its horizon otherwise makes lowering the thrust look cheap.
    min_height: float = -math.inf
    w_floor: float = 1000.0  # 1/m^2
    w_thrust: float = 0.01  # 1/N^2, thrust minus hover thrust
    w_rates: float = 0.05  # s^2/rad^2
    w_thrust_rate: float = 0.05  # 1/N^2, change of thrust per step
    w_rates_rate: float = 0.3  # s^2/rad^2, change of body rates per step
    terminal: float = 5.0  # extra weight of the last step's state terms
    max_fallback_steps: int = 10  # consecutive fallbacks on the last safe plan, then hover
    hover_gain: float = 5.0  # 1/s, attitude error -> body rate of the hover command
    # The cost's cable length and hover thrust: "dataset" (the params given) or "window"
    # (estimated in flight from the history at every step, the params as the prior: a load
    # the controller was not told of; ``MPPIController``'s ``estimate``).
    constants: str = "dataset"
    # What the state terms hold the vehicle and the cable to (a name of ``COSTS``): "vehicle"
    # the reference itself and a vertical cable; "payload" the vehicle's position, velocity and
    # cable direction that the load's reference path requires (``payload_first``).
    cost: str = "vehicle"
    # the payload cost only: the reference's acceleration the cable follows averaged over lean x
    # sqrt(l / g) each way, so the cable leans only as fast as the load swings (``cost.leaned``)
    lean: float = 0.0
    # the payload cost only: the reference's jumps (a setpoint's steps) put back as paths the
    # load can follow, each over shape x sqrt(max(l, |jump|) / g) each way, which the cost
    # tracks (``cost.shaped_jumps``)
    shape: float = 0.0
    # An ensemble's pricing (``predict_candidates_members``): None, the cost of the members'
    # mean; beta >= 0, the mean of the members' costs + beta x their std (docs/control.md).
    # Every member then predicts every candidate: E x one network's compute at equal K.
    risk: float | None = None
    # How an ensemble's members predict the candidates (a name of ``MEMBER_USES``): "all"
    # every member each candidate; "split" candidate k by member k mod E (``SplitMembers``).
    members: str = ALL
    # s: the commands' first-order lags (thrust, roll and pitch rates, yaw rate) the physics
    # model is fed through (``lagged.with_input_lag``; fitted by `identify --input-lag`)
    input_lag: tuple[float, float, float] = NO_LAG
    seed: int = 0

    def __post_init__(self) -> None:
        if self.samples < 2 or self.horizon < 2 or not 2 <= self.knots <= self.horizon:
            raise ValueError(
                f"MPCConfig: need samples >= 2, horizon >= 2 and 2 <= knots <= horizon; got "
                f"{self.samples}, {self.horizon}, {self.knots}"
            )
        if not self.temperature > 0:
            raise ValueError(f"MPCConfig.temperature must be > 0, got {self.temperature}")
        if self.cost not in COSTS:
            raise ValueError(f"MPCConfig.cost: unknown {self.cost!r}; known: {list(COSTS)}")
        if self.constants not in NETWORK_CONSTANTS:
            raise ValueError(
                f"MPCConfig.constants: unknown {self.constants!r}; known: {list(NETWORK_CONSTANTS)}"
            )
        for name in ("lean", "shape"):
            value = getattr(self, name)
            if not 0.0 <= value < math.inf:
                raise ValueError(f"MPCConfig.{name} must be a finite number >= 0, got {value}")
            if value and self.cost != "payload":
                raise ValueError(f"MPCConfig.{name} is the payload cost's (the {self.cost!r} "
                                 f"cost holds the vehicle to the reference as it is): give cost "
                                 f"'payload', or {name} 0; got {name} {value:g}")  # fmt: skip
        if self.risk is not None and not 0.0 <= self.risk < math.inf:
            raise ValueError(
                f"MPCConfig.risk must be None or a finite number >= 0, got {self.risk}"
            )
        if self.members not in MEMBER_USES:
            raise ValueError(f"MPCConfig.members: unknown {self.members!r}; known: "
                             f"{list(MEMBER_USES)}")  # fmt: skip
        check_lag(self.input_lag)
        if self.members == SPLIT and self.risk is not None:
            raise ValueError("MPCConfig.members 'split' gives each candidate one member's cost, "
                             "and risk prices every member's: give one of the two")  # fmt: skip


def knots_for(horizon: int) -> int:
    """The sampler's knots at ``horizon``: the default, or fewer on a shorter horizon."""
    return min(MPCConfig().knots, horizon)


@dataclass
class MPCStats:
    """What happened over a flight: steps, fallbacks by reason, dropped samples, hover steps."""

    steps: int = 0
    fallbacks: Counter = field(default_factory=Counter)  # reason -> steps
    nonfinite_steps: int = 0  # steps where some (not all) samples predicted NaN/inf
    hover_steps: int = 0  # fallback steps that flew the hover command
    estimate_rejected: int = 0  # steps whose in-flight constants were not finite and positive
    novel_steps: int = 0  # with ``MPCConfig.risk``: nominal plans flagged (``Calibration.novel``)
    physics_only_steps: int = 0  # a network paired with physics had no say (``paired``'s window)
    surprised_steps: int = 0  # a calibrated ensemble's tracked interval surprised (``tracked``)

    @property
    def fallback_steps(self) -> int:
        return sum(self.fallbacks.values())


class Command(NamedTuple):
    """What the controller sends: collective thrust and body rates (FLU body frame)."""

    thrust: float  # N
    rates: np.ndarray  # (3,) rad/s


def mppi_weights(cost: np.ndarray, temperature: float) -> np.ndarray | None:
    """Weights (K,) summing to 1 over the finite costs (non-finite ones get 0); None when no
    cost is finite."""
    finite = np.isfinite(cost)
    if not finite.any():
        return None
    c_min = cost[finite].min()
    spread = max(cost[finite].mean() - c_min, 1e-9)
    w = np.zeros_like(cost)
    w[finite] = np.exp(-(cost[finite] - c_min) / (temperature * spread))
    return w / w.sum()


class MPPIController:
    """The sampling MPC (see the module): ``step(state, reference) -> Command``, once per
    measurement, in order; one controller per flight.

    model: a ``CandidateModel`` (a physics one fed through ``config.input_lag``); limits: the
    input box; config: ``MPCConfig`` (default: K = 32, N = 15); params: the vehicle constants
    for hover thrust, cable length and dt (default ``VehicleParams()``); estimate: (x_hist (M,
    13), u_past (M-1, 4)) -> (cable length m, load mass kg), called every step when
    ``config.constants`` is "window". ``stats`` counts steps and fallbacks; ``plan`` is the
    nominal plan (N, 4) for the next step (the last safe plan, shifted)."""

    def __init__(
        self,
        model: CandidateModel,
        limits: InputLimits,
        config: MPCConfig | None = None,
        params: VehicleParams | None = None,
        estimate: ConstantsEstimate | None = None,
    ) -> None:
        self.cfg = cfg = config or MPCConfig()
        self.params = params = params or VehicleParams()
        model = with_input_lag(model, cfg.input_lag, params.dt)
        if cfg.members == SPLIT:
            model = SplitMembers(model, cfg.samples)
        calibration = calibration_of(model)  # a calibrated ensemble's interval is tracked
        if calibration is not None and has_members(model) and not isinstance(model, TrackedMembers):
            model = TrackedMembers(model, calibration, cfg.horizon, constants=params)
        self.model = model
        self.limits = limits
        if (cfg.constants == "window") != (estimate is not None):
            raise ValueError(
                "MPPIController: constants='window' needs an estimate of the constants, and an "
                f"estimate needs constants='window'; got {cfg.constants!r} and "
                f"{'an' if estimate else 'no'} estimate"
            )
        self.estimate = estimate
        self.history = History(max(2, model.history))
        self._use_constants(params.cable_length, params.mass_load)
        self.plan = np.tile(self.hover, (cfg.horizon, 1))  # the last safe plan, shifted
        self.u_prev = self.hover.copy()
        self.std = np.array([cfg.thrust_std, *cfg.rate_std])
        self.interp = _interpolation(cfg.horizon, cfg.knots)  # (N, knots)
        self.rng = np.random.default_rng(cfg.seed)
        self.stats = MPCStats()
        self._fallback_run = 0
        self._found: tuple[Any, np.ndarray, tuple[np.ndarray, np.ndarray]] | None = None
        check_members(model, cfg.risk)
        prepare = getattr(model, "prepare", None)  # see ``CandidateModel``
        if prepare is not None:
            prepare(self.history.m, cfg.samples, cfg.horizon)

    @classmethod
    def from_file(
        cls,
        path,
        limits: InputLimits,
        config: MPCConfig | None = None,
        *,
        threads: int = 1,
        providers: list[str] | None = None,
    ) -> MPPIController:
        """The onboard controller on an exported model (``slungload export --for-mpc``),
        without torch: a ``.mpc.onnx`` graph on ONNX Runtime (``deploy.onboard``; threads,
        providers: its session's; N set to the file's horizon, the knots to at most N) or a
        ``.mpc.npz`` compiled model on numpy + Numba (``deploy.compiled.archive``; any N); the
        vehicle constants from its sidecar."""
        from ..deploy.backends import load_exported  # the file's runtime, only when asked

        model = load_exported(path, threads=threads, providers=providers)
        config = config or MPCConfig()
        if model.horizon is not None:
            config = replace(config, horizon=model.horizon, knots=min(config.knots, model.horizon))
        return cls(model, limits, config, model.params)

    def step(
        self, state: np.ndarray, reference: ReferenceAhead, *, rotation: np.ndarray | None = None
    ) -> Command:
        """One control step: the measured state x_k (13,) and the reference at the N steps
        ahead -> the command to apply now. rotation: the attitude's (3, 3) rotation matrix if
        the caller has it (the hover fallback uses it; default: from the state's quaternion)."""
        state = np.asarray(state, dtype=np.float64)
        reference = self.check_reference(reference)
        if state.shape != (STATE_DIM,):
            raise ValueError(f"step: state must be ({STATE_DIM},), got {state.shape}")
        self.stats.steps += 1
        self.history.push_state(state)
        x_hist, u_past = self.history.window(self.plan[0])
        if self.estimate is not None:
            cable_length, mass_load = (float(c) for c in self.estimate(x_hist, u_past))
            if math.isfinite(cable_length) and math.isfinite(mass_load) and cable_length > 0:
                self._use_constants(cable_length, max(mass_load, 0.0))
            else:  # a NaN in the history: keep the last good constants, so hover stays finite
                self.stats.estimate_rejected += 1
        plan, reason = self._optimise(reference, x_hist, u_past)
        if reason is None:
            self._fallback_run = 0
        else:
            plan = self._fallback(reason, state, reference, rotation)
        u = plan[0].copy()
        self.history.push_input(u)
        self.u_prev = u
        self.plan = np.concatenate([plan[1:], plan[-1:]])  # shifted: the next nominal plan
        return Command(float(u[0]), u[1:].copy())

    def _use_constants(self, cable_length: float, mass_load: float) -> None:
        """The cost's load reference and hover thrust (and the hover command) for these."""
        p = self.params
        self.cable_length = float(cable_length)
        self.hover_thrust = (p.mass_quad + float(mass_load)) * p.gravity
        self.hover = self.limits.clamp(np.array([self.hover_thrust, 0.0, 0.0, 0.0]))

    def check_reference(self, reference: ReferenceAhead) -> ReferenceAhead:
        """The reference as float64 arrays of N rows (a longer one is cut), or ValueError."""
        n = self.cfg.horizon
        p, v, yaw = (np.asarray(a, dtype=np.float64) for a in reference[:3])
        acc = reference.acceleration if isinstance(reference, ReferenceAhead) else None
        if acc is not None:
            acc = np.asarray(acc, dtype=np.float64)
            if acc.shape[1:] != (3,) or len(acc) < n:
                raise ValueError(
                    f"reference: acceleration must be ({n}, 3) for the N = {n} steps ahead; "
                    f"got {acc.shape}"
                )
            acc = acc[:n]
        elif self.cfg.cost == "payload":
            raise ValueError(
                "reference: the payload-first cost (MPCConfig.cost 'payload') needs the "
                f"acceleration of the N = {n} steps ahead (ReferenceAhead.acceleration)"
            )
        shapes_ok = p.shape[1:] == (3,) and v.shape[1:] == (3,) and yaw.ndim == 1
        if not shapes_ok or min(len(p), len(v), len(yaw)) < n:
            raise ValueError(
                f"reference: need position ({n}, 3), velocity ({n}, 3) and yaw ({n},) for the "
                f"N = {n} steps ahead; got {p.shape}, {v.shape}, {yaw.shape}"
            )
        ahead = ReferenceAhead(p[:n], v[:n], yaw[:n], acc)
        if not all(np.isfinite(a).all() for a in ahead if a is not None):
            raise ValueError("reference: the N steps ahead hold NaN or infinite values")
        return ahead

    def ahead(self, reference, k: int) -> ReferenceAhead:
        """Rows k+1 .. k+N of a whole flight's reference as this controller's cost reads them
        (``reference_ahead``): for the "payload" cost the acceleration leaned over
        ``MPCConfig.lean`` x sqrt(l / g) and the jumps shaped by ``MPCConfig.shape``
        (``cost.shaped_jumps``), with the cable length the cost uses."""
        swing = (self.cable_length, self.params.gravity, self.params.dt)
        shape = shape_of(self.cfg, *swing)
        found = self._jumps(reference) if shape.factor else None
        return reference_ahead(reference, k, self.cfg.horizon, lean_rows(self.cfg, *swing),
                               shape, found)  # fmt: skip

    def _jumps(self, reference) -> tuple[np.ndarray, np.ndarray]:
        """``cost.jumps`` of a whole flight's reference, found at its first step and kept while
        the same reference (object and position array) is flown: they read every row, which
        on a long mission would cost each step more than the step's own rows. A reference
        changed in place is read as first seen: give the controller a new one."""
        kept = self._found
        if kept is None or kept[0] is not reference or kept[1] is not reference.position:
            found = jumps(np.asarray(reference.position, float),
                          np.asarray(reference.velocity, float), self.params.dt)  # fmt: skip
            self._found = kept = (reference, reference.position, found)
        return kept[2]

    def target(self, ref: ReferenceAhead) -> VehicleTarget | None:
        """Where the cost holds the vehicle and the cable at this step: ``payload_first`` of
        ``ref`` with the cost's cable length for the "payload" cost, None for "vehicle"."""
        return cost_target(self.cfg, ref, self.cable_length, self.params.gravity)

    def sample(self) -> np.ndarray:
        """K clamped input sequences (K, N, 4) around the nominal plan; row 0 is the plan."""
        cfg = self.cfg
        z = self.rng.standard_normal((cfg.samples, cfg.knots, INPUT_DIM))
        noise = self.interp @ (z * self.std)  # (N, knots) @ (K, knots, 4) -> (K, N, 4)
        noise[0] = 0.0
        return self.limits.clamp(self.plan + noise)

    def _optimise(
        self, ref: ReferenceAhead, x_hist: np.ndarray, u_past: np.ndarray
    ) -> tuple[np.ndarray | None, str | None]:
        samples = self.sample()
        members = self.cfg.risk is not None
        try:
            if members:  # (E, K, N, 13)
                states = self.model.predict_candidates_members(x_hist, u_past, samples)
            else:
                states = self.model.predict_candidates(x_hist, u_past, samples)
        except (RuntimeError, ValueError, FloatingPointError) as exc:
            return None, f"prediction error ({type(exc).__name__})"
        shape = tuple(getattr(states, "shape", ()))
        if (shape[1:] if members else shape) != (*samples.shape[:2], STATE_DIM):
            return None, "prediction of the wrong shape"
        states = np.asarray(states, dtype=np.float64).reshape(-1, *samples.shape[:2], STATE_DIM)
        e, k, n = states.shape[:3]
        costs = trajectory_cost(
            states.reshape(e * k, n, STATE_DIM),
            np.tile(samples, (e, 1, 1)),
            ref,
            self.u_prev,
            self.cfg,
            self.cable_length,
            self.hover_thrust,
            self.target(ref),
        ).reshape(e, k)
        if members:
            cost = priced(costs, self.cfg.risk, getattr(self.model, "member_weights", None))
        else:
            cost = costs[0]
        if members and not getattr(self.model, "trusted", True):
            self.stats.physics_only_steps += 1
        if getattr(self.model, "surprised", False):  # ``tracked.TrackedMembers``
            self.stats.surprised_steps += 1
        if members and hasattr(self.model, "novel"):  # sample 0 is the nominal plan
            self.stats.novel_steps += bool(self.model.novel(states[:, :1])[0])
        finite = np.isfinite(cost) & np.isfinite(states).transpose(1, 0, 2, 3).reshape(k, -1).all(1)
        weights = mppi_weights(np.where(finite, cost, math.inf), self.cfg.temperature)
        if weights is None:
            return None, "non-finite prediction"
        if not finite.all():
            self.stats.nonfinite_steps += 1
        plan = np.einsum("k,knd->nd", weights, samples)
        if not self.limits.contains(plan):
            return None, "plan outside the limits"
        return plan, None

    def _fallback(self, reason: str, state, ref: ReferenceAhead, rotation) -> np.ndarray:
        """The last safe plan (already shifted), or hover after too many fallbacks in a row."""
        self.stats.fallbacks[reason] += 1
        self._fallback_run += 1
        if self._fallback_run <= self.cfg.max_fallback_steps and self.limits.contains(self.plan):
            return self.plan
        self.stats.hover_steps += 1
        if rotation is None:
            rotation = frames.rotation_matrix(state[QUAT])
        return self.hover_command(rotation, float(ref.yaw[0]))

    def hover_command(self, rotation: np.ndarray, yaw: float) -> np.ndarray:
        """(N, 4): hover thrust, body rates that level the vehicle (attitude ``rotation``
        (3, 3), body -> world) at ``yaw``, clamped."""
        rot = np.asarray(rotation, dtype=float)
        if not np.isfinite(rot).all():
            rates = np.zeros(3)
        else:
            c, s = math.cos(yaw), math.sin(yaw)
            target = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
            err = rot.T @ target  # body frame: rotation from the vehicle to the target
            rates = self.cfg.hover_gain * frames.rotvec_from_matrix(err)
        plan = np.tile(self.hover, (self.cfg.horizon, 1))
        plan[0] = self.limits.clamp(np.array([self.hover_thrust, *rates]))
        return plan


def _interpolation(n: int, knots: int) -> np.ndarray:
    """(n, knots) linear interpolation from knots evenly spread over steps 0 .. n-1."""
    at = np.linspace(0.0, knots - 1.0, n)
    return np.maximum(1.0 - np.abs(at[:, None] - np.arange(knots)), 0.0)
