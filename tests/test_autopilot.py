"""The MPC on an autopilot, flown through the simulated PX4 on 127.0.0.1 (lockstep): the
handshake, the faults and the failsafes, each ending in a stated state with nothing
non-finite sent; the flight's .tlog imports. The MPC's model is the physics model exported
for the onboard MPC (ONNX, N = 10): the bridge runs on numpy + onnxruntime + pymavlink."""

from __future__ import annotations

import gc
import math
import os
import socket
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from slungload.autopilot import px4
from slungload.autopilot.bridge import Bridge
from slungload.autopilot.config import BridgeConfig, SilConfig
from slungload.autopilot.sil import SilEndpoint
from slungload.control.mppi import MPCConfig
from slungload.deploy.backends import load_exported
from slungload.deploy.candidates import export_for_mpc

mavlink = px4.mavlink


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("autopilot")
    return export_for_mpc("physics", folder / "physics.mpc.onnx", horizon=10).model


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def configs(port: int, **bridge) -> tuple[SilConfig, BridgeConfig]:
    # a lockstep period waits up to 0.5 s (wall) for its set-point: on a busy machine a
    # shorter wait lets the simulation run ahead of a bridge it should wait for
    sil = SilConfig(connection=f"udpout:127.0.0.1:{port}", lockstep_wait=0.5,
                    heartbeat_period=0.1, duration=60.0)  # fmt: skip
    # the ages: a busy machine (CI's two workers) can take longer than the default 0.1 s of
    # wall clock between two lockstep periods; the stale-stream tests stop a stream for 1 s
    fly = BridgeConfig(connection=f"udpin:127.0.0.1:{port}", arm=True, offboard=True,
                       stream_before_switch=0.2, duration=1.0, hover_time=0.3,
                       mpc=MPCConfig(samples=16), connect_timeout=5.0, max_state_age=0.4,
                       max_load_age=0.4)  # fmt: skip
    return sil, replace(fly, **bridge)


def fly_through(model_file, sil_cfg: SilConfig, fly_cfg: BridgeConfig, on_log=None):
    """One flight: the endpoint in a thread, the bridge here; (bridge result, endpoint, log)."""
    endpoint = SilEndpoint(sil_cfg)
    thread = threading.Thread(target=endpoint.run, daemon=True)
    thread.start()
    model = model_file if hasattr(model_file, "params") else load_exported(model_file)
    lines: list[str] = []

    def log(line: str) -> None:
        lines.append(line)
        if on_log is not None:
            on_log(line, endpoint)

    try:
        result = Bridge(fly_cfg, model, model.params, log=log).run()
        time.sleep(0.2)  # the endpoint takes the last messages
    finally:
        endpoint.stop()
        thread.join(5.0)
    return result, endpoint, lines


def assert_finite_on_the_wire(endpoint: SilEndpoint) -> None:
    assert endpoint.log.setpoints
    for _, throttle, rates in endpoint.log.setpoints:
        assert math.isfinite(throttle) and np.isfinite(rates).all()
    assert not endpoint.log.ignored  # nothing non-finite or unusable arrived either


@pytest.fixture(scope="module")
def flown(model_file, tmp_path_factory):
    """A short lockstep flight, holding where OFFBOARD started, recorded."""
    tlog = tmp_path_factory.mktemp("tlog") / "flight.tlog"
    sil, fly = configs(free_port(), tlog=tlog, duration=1.5)  # import keeps >= 1 s pieces
    frozen: list[int] = []  # the objects left out of the collector while the MPC flies

    def on_log(line: str, _) -> None:
        if "the MPC flies" in line:
            frozen.append(gc.get_freeze_count())

    flight = fly_through(model_file, sil, fly, on_log=on_log)
    assert frozen and frozen[0] > 10_000  # no full collection walks the model, numpy, ...
    assert gc.get_freeze_count() == 0  # ... and the caller's heap is left as it was
    return (*flight, tlog)


def test_a_lockstep_flight_ends_handed_back_with_nothing_non_finite_sent(flown):
    result, endpoint, _, _ = flown
    assert result.end == "flight complete" and result.steps == round(1.5 / 0.03)
    assert not result.safety.counts and result.mpc.fallback_steps == 0
    assert_finite_on_the_wire(endpoint)
    modes = [(mode, why) for _, mode, why in endpoint.log.modes]
    assert modes == [("offboard", "commanded"), ("position", "commanded")]  # handed back
    start = next(t for t, mode, _ in endpoint.log.modes if mode == "offboard")
    track = np.array([p for t, p, _ in endpoint.log.track if t >= start])
    assert np.abs(track - track[0]).max() < 0.3  # m: it held its point
    acks = dict(endpoint.log.acks)  # already armed (airborne in position mode): no arming
    assert acks == {mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: mavlink.MAV_RESULT_ACCEPTED,
                    mavlink.MAV_CMD_DO_SET_MODE: mavlink.MAV_RESULT_ACCEPTED}  # fmt: skip


def test_a_lockstep_flight_on_a_compiled_file(tmp_path):
    """The bridge flies the compiled format too (numpy + Numba, the config's N)."""
    compiled = export_for_mpc("physics", tmp_path, horizon=10, format="compiled").model
    sil, fly = configs(free_port(), duration=0.6, mpc=MPCConfig(samples=16, horizon=8))
    result, endpoint, _ = fly_through(compiled, sil, fly)
    assert result.end == "flight complete" and result.steps == round(0.6 / 0.03)
    assert not result.safety.counts and result.mpc.fallback_steps == 0
    assert_finite_on_the_wire(endpoint)


def test_in_lockstep_the_sil_flies_the_flight_control_flies(tmp_path):
    """`sil --maneuver M --seed S --start-on-offboard` and `fly` from the simulator's start,
    with its warm-up as --settle, its arena as --box and its limits as the MPC's box: the
    flight `slungload control` flies in process (``closed_loop.fly``, same model, MPC and
    seed), to the float32 rounding of MAVLink's fields; a SIL whose clock runs before OFFBOARD
    (the PID holding the vehicle meanwhile) does not give it."""
    from slungload.control.closed_loop import fly
    from slungload.control.mpc import SamplingMPC
    from slungload.control.mppi import InputLimits
    from slungload.sim.dataset import vehicle_params
    from slungload.sim.maneuvers import ARENA_BOX
    from slungload.sim.plants import plant_config

    model = load_exported(export_for_mpc("physics", tmp_path / "p.mpc.npz", horizon=10,
                                         format="compiled").model)  # fmt: skip
    sim, maneuver, seed, steps = plant_config("default"), "fast_8_lap_xyz", 101, 30
    mpc = MPCConfig(samples=16, horizon=10)
    limits = InputLimits.from_sim(sim)
    control = SamplingMPC(model, limits, replace(mpc, seed=seed), vehicle_params(sim))
    here = fly(maneuver, seed, control, label="mpc", config=sim, steps=steps)
    assert here.stopped is None

    def through_sil(start_on_offboard: bool) -> np.ndarray:
        port = free_port()
        # a long lockstep wait keeps a slow bridge's flight identical; the running clock's
        # flight keeps the short one (its heartbeats come with simulated time)
        wait = 10.0 if start_on_offboard else configs(port)[0].lockstep_wait
        sil = replace(configs(port)[0], maneuver=maneuver, seed=seed, steps=steps,
                      start_on_offboard=start_on_offboard, lockstep_wait=wait,
                      hover_throttle=sim.total_mass * sim.gravity / sim.max_thrust)  # fmt: skip
        start = SilEndpoint(sil).start
        _, bridge = configs(port)
        bridge = replace(bridge, maneuver=maneuver, seed=seed, duration=steps * sim.control_dt,
                         settle=sim.warmup, origin=(*map(float, start), 0.0), box=ARENA_BOX,
                         newtons_per_throttle=sim.max_thrust, rate_max=sim.max_rate, mpc=mpc,
                         max_state_age=5.0, max_load_age=5.0)  # fmt: skip
        result, _, _ = fly_through(model, sil, bridge)
        assert result.end == "flight complete" and not result.safety.counts
        return np.array(result.states)

    there = through_sil(True)
    assert there.shape == here.states.shape  # warm-up and recorded steps alike
    assert np.abs(there - here.states).max() < 1e-5  # m, m/s: float32 on the wire
    running = through_sil(False)
    assert np.abs(running[: len(there)] - there[: len(running)]).max() > 1e-3


def test_the_bridge_reference_is_the_simulators_from_the_same_start():
    """From the simulator's start, heading 0, its warm-up as the settle and its arena as the
    box, the bridge's reference of every maneuver is the one the simulator's controller gets,
    row for row; a heading turns it, and --duration cuts it after the settle."""
    from slungload.autopilot.reference import flight_reference as bridge_reference
    from slungload.sim.flight import flight_setup
    from slungload.sim.maneuvers import ARENA_BOX, MANEUVERS
    from slungload.sim.plants import plant_config

    sim = plant_config("default")
    for name in MANEUVERS:
        setup = flight_setup(name, 7, sim)
        ours = bridge_reference(setup.plant.p, 0.0, sim.control_dt, name, 7, None, sim.warmup,
                                ARENA_BOX)  # fmt: skip
        for field in ("position", "velocity", "acceleration", "yaw"):
            np.testing.assert_array_equal(getattr(ours, field), getattr(setup.reference, field),
                                          err_msg=f"{name} {field}")  # fmt: skip
    turned = bridge_reference(np.zeros(3), np.pi / 2, 0.03, "xy_step", 7, 1.5, 0.3)
    assert len(turned.yaw) == 10 + 50 and np.allclose(turned.yaw[:10], np.pi / 2)
    plain = bridge_reference(np.zeros(3), 0.0, 0.03, "xy_step", 7, 1.5, 0.3)
    np.testing.assert_allclose(turned.position[:, 0], -plain.position[:, 1], atol=1e-12)


def test_the_new_options_refuse_bad_values(run_cli, model_file, capsys):
    with pytest.raises(ValueError, match="origin needs four"):
        BridgeConfig(origin=(0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="box needs"):
        BridgeConfig(box=(1.0, -1.0, 0.0, -1.0, 1.0, 2.0))
    with pytest.raises(ValueError, match="settle"):
        BridgeConfig(settle=-1.0)
    with pytest.raises(ValueError, match="steps"):
        SilConfig(steps=0)
    with pytest.raises(SystemExit) as exit_:  # argparse's own refusal
        run_cli("fly", model_file, "--origin", "0,0,1")
    assert exit_.value.code == 2 and "X,Y,Z,YAW" in capsys.readouterr().err


def test_the_fifo_scheduler_is_asked_for_and_given_back(tmp_path, model_file, run_cli,
                                                        monkeypatch):  # fmt: skip
    """--fifo-priority: the loop under the real-time scheduler, the one before restored after;
    an OS that refuses it ends the command before anything is connected."""
    with pytest.raises(ValueError, match="1-99"):
        BridgeConfig(fifo_priority=0)
    if not hasattr(os, "sched_setscheduler"):
        pytest.skip("no real-time scheduler on this OS")
    with monkeypatch.context() as m:

        def refuse(*_):
            raise PermissionError(1, "Operation not permitted")

        m.setattr(os, "sched_setscheduler", refuse)
        code, _, err = run_cli("fly", model_file, "--fifo-priority", "10")
        assert code == 2 and "refused the real-time FIFO scheduler" in err
    before = os.sched_getscheduler(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except PermissionError:
        pytest.skip("this OS refuses the FIFO scheduler to this user")
    os.sched_setscheduler(0, before, os.sched_param(0))
    compiled = export_for_mpc("physics", tmp_path, horizon=10, format="compiled").model
    sil, fly = configs(free_port(), duration=0.3, mpc=MPCConfig(samples=16, horizon=8),
                       fifo_priority=1)  # fmt: skip
    seen: list[int] = []

    def on_log(line: str, _) -> None:
        if "the MPC flies" in line:
            seen.append(os.sched_getscheduler(0))

    result, _, _ = fly_through(compiled, sil, fly, on_log=on_log)
    assert result.end == "flight complete"
    assert seen == [os.SCHED_FIFO] and os.sched_getscheduler(0) == before


def test_a_lockstep_flight_priced_with_physics(tmp_path):
    """`fly --with-physics --risk 1 --trust-window 5`: the compiled file's model and the physics
    model of its constants as two members (numpy only), the file's model trusted throughout (it
    predicts the flown steps as physics does); a --risk without members, --members split of
    one network, or a trust window without physics, is refused before any link is opened."""
    from slungload.autopilot.bridge import fly

    compiled = export_for_mpc("physics", tmp_path / "p.mpc.npz", horizon=10,
                              format="compiled").model  # fmt: skip
    sil, bridge = configs(free_port(), duration=0.6, with_physics=True,
                          mpc=MPCConfig(samples=16, horizon=8, risk=1.0))  # fmt: skip
    endpoint = SilEndpoint(sil)
    thread = threading.Thread(target=endpoint.run, daemon=True)
    thread.start()
    try:  # with the trust window: the file's model predicts the flown steps as physics does
        result = fly(compiled, replace(bridge, trust_window=5))
    finally:
        endpoint.stop()
        thread.join(5.0)
    assert result.end == "flight complete" and result.steps == round(0.6 / 0.03)
    assert not result.safety.counts and result.mpc.fallback_steps == 0
    assert result.mpc.physics_only_steps == 0
    assert result.summary().startswith("flight complete: 20 MPC steps")
    assert "physics alone" not in result.summary()  # trusted throughout
    result.mpc.physics_only_steps = 5
    assert "physics alone priced 25 % of the steps" in result.summary()
    assert "surprised" not in result.summary()
    result.mpc.surprised_steps = 2  # a calibrated ensemble's tracked interval (control.tracked)
    assert "the ensemble surprised on 10 % of the steps" in result.summary()
    assert_finite_on_the_wire(endpoint)
    with pytest.raises(ValueError, match="one network"):
        fly(compiled, replace(bridge, with_physics=False))
    split = MPCConfig(samples=16, horizon=8, members="split")
    with pytest.raises(ValueError, match="no members to call one by one"):
        fly(compiled, replace(bridge, with_physics=False, mpc=split))
    with pytest.raises(ValueError, match="give --risk"):
        replace(bridge, mpc=MPCConfig())
    with pytest.raises(ValueError, match="give --with-physics"):
        replace(bridge, with_physics=False, trust_window=5)


def test_offboard_is_refused_without_a_setpoint_stream_and_accepted_after():
    port = free_port()
    endpoint = SilEndpoint(configs(port)[0])
    thread = threading.Thread(target=endpoint.run, daemon=True)
    thread.start()
    conn = px4.connect(f"udpin:127.0.0.1:{port}", system=1, component=191)
    try:
        conn.wait_heartbeat(timeout=5)

        def ask_offboard() -> int:
            flag = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            conn.mav.command_long_send(1, 1, mavlink.MAV_CMD_DO_SET_MODE, 0, flag, px4.OFFBOARD,
                                       0, 0, 0, 0, 0)  # fmt: skip
            ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
            return ack.result

        assert ask_offboard() == mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        for _ in range(10):  # a stream of hover set-points
            conn.mav.send(px4.attitude_target(0, 1, 0.5, np.zeros(3)))
            conn.recv_match(type="ODOMETRY", blocking=True, timeout=2)
        assert ask_offboard() == mavlink.MAV_RESULT_ACCEPTED
        assert endpoint.mode == px4.OFFBOARD
    finally:
        endpoint.stop()
        thread.join(5.0)
        conn.close()


def test_a_stopped_state_stream_hovers_then_hands_back(model_file):
    # the state's age on the bridge's clock (wall): the default 0.1 s, so that the gap shows
    # however fast the lockstep simulation runs (a stalled bridge stalls it too)
    sil, fly = configs(free_port(), duration=3.0, max_state_age=0.1)

    def stop_the_state(line: str, endpoint: SilEndpoint) -> None:
        if "the MPC flies" in line:  # 0.15 s of flight, then 1 s without the vehicle's state
            endpoint.state_gap = (endpoint.t + 0.15, endpoint.t + 1.15)

    result, endpoint, _ = fly_through(model_file, sil, fly, stop_the_state)
    assert result.end == "handed back: stale state"
    assert result.safety.counts == {"stale state": 1}
    assert_finite_on_the_wire(endpoint)
    assert endpoint.log.modes[-1][1:] == ("position", "commanded")


def test_a_stopped_load_stream_hovers_then_hands_back(model_file):
    # the load's age: the default 0.1 s of wall clock. In real time, not lockstep: a lockstep
    # simulation runs on while only the load is missing, and on a fast machine its 1 s gap
    # (33 MPC steps) can pass in less wall time than that
    sil, fly = configs(free_port(), duration=3.0, max_load_age=0.1)
    sil = replace(sil, lockstep=False)

    def stop_the_load(line: str, endpoint: SilEndpoint) -> None:
        if "the MPC flies" in line:
            endpoint.load_gap = (endpoint.t + 0.15, endpoint.t + 1.15)

    result, endpoint, _ = fly_through(model_file, sil, fly, stop_the_load)
    assert result.end == "handed back: stale load"
    assert result.safety.counts == {"stale load": 1}
    assert_finite_on_the_wire(endpoint)
    assert endpoint.log.modes[-1][1:] == ("position", "commanded")


def test_a_tenth_of_the_telemetry_dropped(model_file):
    """Lost ODOMETRY: the flight completes, or a run of losses is a stale measurement; either
    way it ends handed back to position mode with nothing non-finite sent."""
    sil, fly = configs(free_port())
    result, endpoint, _ = fly_through(model_file, replace(sil, drop=0.1), fly)
    assert result.end in ("flight complete", "handed back: stale state", "handed back: stale load")
    assert endpoint.log.modes[-1][1:] == ("position", "commanded")
    assert_finite_on_the_wire(endpoint)


def test_fifty_milliseconds_of_jitter_on_the_telemetry(model_file):
    """Every ODOMETRY delayed by up to 50 ms (wall clock; some arrive out of order): the flight
    completes and hands back, nothing non-finite on the wire."""
    sil, fly = configs(free_port())
    result, endpoint, _ = fly_through(model_file, replace(sil, jitter=0.05), fly)
    assert endpoint.log.delayed > 2 * result.steps  # the vehicle's and the load's, each step
    assert result.end == "flight complete" and not result.safety.counts
    assert endpoint.log.modes[-1][1:] == ("position", "commanded")
    assert_finite_on_the_wire(endpoint)


def test_leaving_offboard_mid_flight_stops_the_commands(model_file):
    # in real time: the pilot switches 0.3 s (wall) into a 3 s flight, which a lockstep
    # simulation on a fast machine could finish first
    sil, fly = configs(free_port(), duration=3.0)
    sil = replace(sil, lockstep=False)
    switched = []

    def pilot(line: str, endpoint: SilEndpoint) -> None:
        if "the MPC flies" in line:

            def switch() -> None:
                endpoint.switch_mode("position")
                switched.append(endpoint.t)

            threading.Timer(0.3, switch).start()

    result, endpoint, _ = fly_through(model_file, sil, fly, pilot)
    assert result.end == "left offboard" and 0 < result.steps < 3.0 / 0.03
    last = endpoint.log.setpoints[-1][0]
    assert last <= switched[0] + sil.heartbeat_period + 2 * 0.03  # s: within a heartbeat
    assert endpoint.log.modes[-1][1:] == ("position", "pilot")
    assert_finite_on_the_wire(endpoint)


def test_malformed_and_unknown_messages_are_ignored(model_file):
    sil, fly = configs(free_port())
    junk = [b"\xfd\x05\x00\x00\x01\x01\x01\x60\xea\x00hello\x00\x00",  # unknown id 60000
            b"\xfe\x09garbage that is not mavlink", bytes(range(40))]  # fmt: skip

    def spray(line: str, endpoint: SilEndpoint) -> None:
        if "the MPC flies" in line:
            for data in junk:
                endpoint.conn.write(data)  # to the bridge
                socket.socket(socket.AF_INET, socket.SOCK_DGRAM).sendto(
                    data, endpoint.conn.port.getsockname()
                )  # to the endpoint

    result, endpoint, _ = fly_through(model_file, sil, fly, spray)
    assert result.end == "flight complete" and sum(result.ignored.values()) > 0
    assert sum(endpoint.log.ignored.values()) > 0
    for _, throttle, rates in endpoint.log.setpoints:
        assert math.isfinite(throttle) and np.isfinite(rates).all()


def test_shadow_mode_computes_and_sends_nothing(model_file):
    sil, fly = configs(free_port(), dry_run=True, arm=False, offboard=False, duration=0.5)
    sil = replace(sil, lockstep=False)  # nothing sent: nothing would pace a lockstep
    result, endpoint, _ = fly_through(model_file, sil, fly)
    assert result.end == "flight complete" and result.steps > 0 and result.sent == 0
    assert not endpoint.log.setpoints and np.isfinite(result.commands).all()


# What the onboard install leaves out: the bridge must run without any of it.
BLOCK = """
import importlib.abc, sys
class Blocked(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("torch", "lightning", "mujoco", "roma", "numba", "matplotlib"):
            raise ImportError(f"{name} is not in the onboard install")
sys.meta_path.insert(0, Blocked())
"""


def test_the_bridge_runs_without_torch_and_a_killed_bridge_meets_the_failsafe(model_file):
    """The bridge in its own process (torch and MuJoCo blocked) flies until killed; the
    endpoint then switches to position mode after COM_OF_LOSS_T without set-points."""
    port = free_port()
    sil, _ = configs(port)
    sil = replace(sil, lockstep_wait=0.05)  # without set-points COM_OF_LOSS_T passes quickly
    code = BLOCK + (
        "from slungload.autopilot.bridge import fly\n"
        "from slungload.autopilot.config import BridgeConfig\n"
        f"cfg = BridgeConfig(connection='udpin:127.0.0.1:{port}', arm=True, offboard=True, "
        "stream_before_switch=0.2, duration=60.0)\n"
        "fly(" + repr(str(model_file)) + ", cfg, log=lambda line: print(line, 'torch' in "
        "sys.modules, 'mujoco' in sys.modules, flush=True))\n"
    )
    endpoint = SilEndpoint(sil)
    thread = threading.Thread(target=endpoint.run, daemon=True)
    thread.start()
    bridge = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        line = ""
        while "the MPC flies" not in line:
            line = bridge.stdout.readline()
            assert line, "the bridge ended before it flew"
        assert line.split()[-2:] == ["False", "False"]  # neither torch nor MuJoCo loaded
        time.sleep(0.3)
        bridge.kill()
        bridge.wait(5)
        deadline = time.monotonic() + 10.0
        while endpoint.mode == px4.OFFBOARD and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        bridge.kill()
        endpoint.stop()
        thread.join(5.0)
    t, mode, why = endpoint.log.modes[-1]
    assert (mode, why) == ("position", "offboard loss (COM_OF_LOSS_T)")
    last = endpoint.log.setpoints[-1][0]
    assert sil.of_loss_timeout < t - last <= sil.of_loss_timeout + 0.1
    for _, throttle, rates in endpoint.log.setpoints:
        assert math.isfinite(throttle) and np.isfinite(rates).all()


def test_a_recorded_flight_imports(flown, tmp_path):
    from slungload.data.importing import import_logs

    tlog = flown[3]
    assert tlog.stat().st_size > 0
    done = import_logs([tlog], tmp_path / "data", progress=False)
    assert len(done.flights) == 1 and 1.0 / 0.03 <= sum(done.flights.values()) <= 1.7 / 0.03
    assert done.params.mass_load > 0


@pytest.mark.slow
def test_flights_flown_through_the_bridge_import_and_train(tmp_path, run_cli):
    """fly -> import -> train: three short lockstep flights recorded as .tlog become a dataset
    (one flight per split) that trains (the compiled file: a fast bridge)."""
    model = export_for_mpc("physics", tmp_path, horizon=10, format="compiled").model
    logs = []
    for seed in (1, 2, 3):
        logs.append(tmp_path / f"f{seed}.tlog")
        sil, fly = configs(free_port(), tlog=logs[-1], duration=4.0, maneuver="roll_35", seed=seed)
        result, _, _ = fly_through(model, replace(sil, seed=seed), fly)
        assert result.end == "flight complete" and result.steps == round(4.0 / 0.03)
    code, _, err = run_cli("import", *logs, "--out", tmp_path / "ds")
    assert code == 0, err
    run = tmp_path / "run"
    code, out, err = run_cli("train", "--data", tmp_path / "ds", "--preset", "quick",
                             "--model", "physics-step", "--out", run, "--quiet")  # fmt: skip
    assert code == 0, err
    assert (run / "best.ckpt").is_file() and "epochs" in out


def test_fly_says_when_nothing_answers(run_cli, model_file):
    port = free_port()
    code, _, err = run_cli("fly", model_file, "--connection", f"udpin:127.0.0.1:{port}",
                           "--connect-timeout", "0.3")  # fmt: skip
    assert code == 2 and "no heartbeat from system 1" in err and "Traceback" not in err
