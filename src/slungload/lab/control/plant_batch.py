"""K copies of one flight's plant stepped together: the oracle MPC's look-ahead (a benchmark).

``PlantBatch.advance`` does for K command plans at once what ``Plant.advance`` does for one,
period after period: the latency (the held command first), the thrust scale and sag, the
thrust lag and rate loop (MuJoCo actuators), and every substep the drag, downwash and wind
forces from Python. MuJoCo steps the K states with ``mujoco.rollout``, one substep per call,
because the Python-side forces depend on the state they act on; the forces are evaluated for
all K in numpy (``Aero``'s batched methods). The wind is held at one value for the plans.

MuJoCo's own warm start of the cable's constraint solver is not carried between the calls, so
the states agree with ``Plant.advance`` to the solver's tolerance, not bit for bit
(tests/test_control_study.py measures it).
"""

from __future__ import annotations

import mujoco
import numpy as np
from mujoco import rollout

from ...frames import rotation_matrix
from ...sim.chain import ChainPlant, RotorLoop
from ...sim.mjcf import THRUST_ACTUATOR
from ...sim.plant import Plant

_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS  # time, qpos, qvel, act (no mocap, no plugins)
_CONTROL = mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_XFRC_APPLIED


DIMS = {"p": 3, "v": 3, "q": 4, "p_load": 3, "v_load": 3}  # what a look-ahead records


class _Batch:
    """What both families' look-aheads share: K copies of the plant's MuJoCo state (time,
    qpos, qvel, act), stepped one substep at a time by ``mujoco.rollout`` under ``control``
    (a MuJoCo state spec: what the Python side sets between the steps)."""

    control: int = _CONTROL

    def __init__(self, plant: Plant | ChainPlant, threads: int = 1) -> None:
        m = plant.model
        if mujoco.mj_stateSize(m, _STATE) != 1 + m.nq + m.nv + m.na:
            raise ValueError(
                f"{type(self).__name__} expects a model whose state is time, qpos, qvel, act"
            )
        self.plant = plant
        self.threads = threads
        self._ncontrol = mujoco.mj_stateSize(m, self.control)
        self._datas = [mujoco.MjData(m) for _ in range(threads)]
        self._pool = rollout.Rollout(nthread=threads) if threads > 1 else None

    def _start(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """K copies of the plant's state now (K, nstate), the step's output (K, 1, nstate) and
        a zero control (K, 1, ncontrol)."""
        m = self.plant.model
        state0 = np.empty(mujoco.mj_stateSize(m, _STATE))
        mujoco.mj_getState(m, self.plant.data, state0, _STATE)
        state = np.tile(state0, (k, 1))
        return state, np.empty((k, 1, state.shape[1])), np.zeros((k, 1, self._ncontrol))

    def _step(self, models, state: np.ndarray, control: np.ndarray, out: np.ndarray) -> None:
        """One MuJoCo step of every row of ``state`` (K, nstate) into ``out`` (K, 1, nstate)."""
        runner = self._pool.rollout if self._pool is not None else rollout.rollout
        runner(models, self._datas, state, control, control_spec=self.control, skip_checks=True,
               nstep=1, state=out)  # fmt: skip


class PlantBatch(_Batch):
    """Look-ahead of a ``Plant``: K plans from its state now, stepped together (see module).

    threads: MuJoCo threads stepping the K states (``mujoco.rollout``'s pool).
    """

    def __init__(self, plant: Plant, threads: int = 1) -> None:
        super().__init__(plant, threads)
        m = plant.model
        self._qpos = 1
        self._qvel = 1 + m.nq
        self._act = 1 + m.nq + m.nv + THRUST_ACTUATOR  # the lagged thrust, as Plant.thrust

    def advance(self, plans: np.ndarray, wind: np.ndarray) -> dict[str, np.ndarray]:
        """Fly K plans (K, N, 4) (thrust N, body rates rad/s), each command held for one
        control period, from the plant's state now in the wind (3,) m/s; the plant is not
        touched. Returns the state after each period: p, v, p_load, v_load (K, N, 3) world
        frame, q (K, N, 4) w-x-y-z."""
        plant = self.plant
        cfg, params, aero = plant.cfg, plant.params, plant.aero
        k_count, n_steps = plans.shape[:2]
        m, d = plant.model, plant.data
        qp, qv, act = self._qpos, self._qvel, self._act
        quad, load = plant.quad, plant.load
        use_aero = aero.drag or aero.downwash
        ideal_rates = not cfg.effects.rate_loop
        wind = np.asarray(wind, dtype=float)

        state, out, control = self._start(k_count)
        ctrl = control[:, 0, : m.nu]
        xfrc = control[:, 0, m.nu :].reshape(k_count, m.nbody, 6)
        ctrl[:] = d.ctrl  # the command still held for the latency
        held_rates = np.tile(plant.command[1], (k_count, 1))
        # MuJoCo's xmat after a step is the kinematics of the state before it: what the
        # plant's forces read at the next substep
        rot = np.tile(d.xmat[quad].reshape(3, 3), (k_count, 1, 1))
        models = [m] * k_count
        thrust_cap = cfg.max_thrust

        record = {name: np.empty((k_count, n_steps, dim)) for name, dim in DIMS.items()}
        lag = cfg.effects.thrust_lag
        for j in range(n_steps):
            time = plant.time + j * cfg.control_dt
            scale = params.thrust_scale * (1.0 - params.battery_sag * time)
            command = np.empty((k_count, m.nu))
            command[:, THRUST_ACTUATOR] = np.clip(plans[:, j, 0] * scale, 0.0, thrust_cap)
            command[:, THRUST_ACTUATOR + 1 : THRUST_ACTUATOR + 4] = plans[:, j, 1:4]
            for s in range(cfg.substeps):
                if s == plant.latency_steps:
                    ctrl[:] = command
                    held_rates = plans[:, j, 1:4]
                if ideal_rates:
                    state[:, qv + 3 : qv + 6] = held_rates
                if use_aero:
                    thrust = state[:, act] if lag else ctrl[:, THRUST_ACTUATOR]
                    p, p_load = state[:, qp : qp + 3], state[:, qp + 7 : qp + 10]
                    v, v_load = state[:, qv : qv + 3], state[:, qv + 6 : qv + 9]
                    wake = (aero.wake_velocities(p, rot, thrust, p_load) if aero.downwash
                            else np.zeros((k_count, 3)))  # fmt: skip
                    xfrc[:, quad, 0:3] = aero.vehicle_forces(v, rot, thrust, wind)
                    xfrc[:, load, 0:3] = aero.load_forces(v_load, wind, wake)
                before = state[:, qp + 3 : qp + 7]
                self._step(models, state, control, out)
                if use_aero:
                    rot = rotation_matrix(before)  # normalised, as MuJoCo's xmat
                state = out[:, 0].copy()  # the next call writes into out
            record["p"][:, j] = state[:, qp : qp + 3]
            record["q"][:, j] = state[:, qp + 3 : qp + 7]
            record["p_load"][:, j] = state[:, qp + 7 : qp + 10]
            record["v"][:, j] = state[:, qv : qv + 3]
            record["v_load"][:, j] = state[:, qv + 6 : qv + 9]
        return record


class ChainBatch(_Batch):
    """Look-ahead of a ``sim.chain.ChainPlant``: K plans from its state now, stepped together
    (as ``PlantBatch``; the rotors' loop and the drag are the plant's own ``RotorLoop`` and
    ``ChainForces``, run for K states between the MuJoCo steps)."""

    control = mujoco.mjtState.mjSTATE_XFRC_APPLIED  # no MuJoCo actuators: forces only

    def advance(self, plans: np.ndarray, wind: np.ndarray) -> dict[str, np.ndarray]:
        """As ``PlantBatch.advance``: K plans (K, N, 4) from the plant's state now in the wind
        (3,) m/s -> p, v, p_load, v_load (K, N, 3), q (K, N, 4) w-x-y-z after each period."""
        plant = self.plant
        cfg, m = plant.cfg, plant.model
        k_count, n_steps = plans.shape[:2]
        qv, lq, lv = 1 + m.nq, 1 + plant.load_qpos, 1 + m.nq + plant.load_qvel
        wind = np.asarray(wind, dtype=float)
        state, out, control = self._start(k_count)
        xfrc = control[:, 0].reshape(k_count, m.nbody, 6)
        loop = RotorLoop(cfg, plant.params, k_count)
        loop.take(plant.rotors, k_count)
        thrust = np.full(k_count, plant.command[0])  # the command still held for the latency
        rates = np.tile(plant.command[1], (k_count, 1))
        models = [m] * k_count
        record = {name: np.empty((k_count, n_steps, dim)) for name, dim in DIMS.items()}
        for j in range(n_steps):
            scale = plant.scale(plant.time + j * cfg.control_dt)
            for s in range(cfg.substeps):
                if s == plant.latency_steps:
                    thrust, rates = plans[:, j, 0], plans[:, j, 1:4]
                if loop.ideal:
                    state[:, qv + 3 : qv + 6] = rates
                force_b, torque_b = loop.wrench(thrust, rates, state[:, qv + 3 : qv + 6], scale)
                rot = rotation_matrix(state[:, 4:8])
                xfrc[:, plant.quad, 0:3], xfrc[:, plant.quad, 3:6] = plant.forces.vehicle(
                    rot, state[:, qv : qv + 3], wind, force_b, torque_b
                )
                xfrc[:, plant.load, 0:3] = plant.forces.load(state[:, lv : lv + 3], wind)
                self._step(models, state, control, out)
                state = out[:, 0].copy()
            record["p"][:, j], record["q"][:, j] = state[:, 1:4], state[:, 4:8]
            record["p_load"][:, j] = state[:, lq : lq + 3]
            record["v"][:, j], record["v_load"][:, j] = state[:, qv : qv + 3], state[:, lv : lv + 3]
        return record


def lookahead(plant: Plant | ChainPlant, threads: int = 1) -> PlantBatch | ChainBatch:
    """The look-ahead of a plant of either family."""
    return (
        ChainBatch(plant, threads) if isinstance(plant, ChainPlant) else PlantBatch(plant, threads)
    )
