"""The flight's own physics at import and in ``inspect`` (``consistency.physics_checks``) and
a second log's residual against the tracks' noise (``alignment.noise_floor``).

Simulated datasets and a synthetic flight with motion-capture and IMU-level noise must pass;
the four kinds of wrong data that the older checks accepted must be refused with exit status
2, the quantity, the value and the likely cause, and nothing written: a w-x-y-z quaternion
read as x-y-z-w at a heading near 180 deg, the load in another frame without vehicle
constants, a hover throttle 40 % off, and the recording of a repeat of the mission as the
second log.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from log_files import PARAMS, default_columns, truth, write_csv

from slungload import frames
from slungload.cli import main
from slungload.data.alignment import RESIDUAL, align_tracks, noise_floor
from slungload.data.consistency import (
    CABLE_PULL,
    THRUST,
    THRUST_AXIS,
    THRUST_SCALE,
    UPRIGHT,
    ConsistencyError,
    ConsistencyLimits,
    accelerations,
    flight_checks,
    physics_checks,
)
from slungload.data.importing import ImportOptions, SecondLog, import_logs
from slungload.data.readers.logs import LogError, Stream
from slungload.data.summary import summarize

TOTAL = PARAMS.mass_quad + PARAMS.mass_load
HOVER = 0.5  # the throttle that holds vehicle and load


def circling(t, *, heading=math.pi, radius=1.5, rate=2.0, seed=0, noise=True):
    """An exact flight in the published schema: the vehicle circles at ``rate`` rad/s
    (6 m/s^2, tilted about 30 deg), the load on the cone that its pull balances, body z along
    the centre of mass's specific force, heading ``heading`` rad (+- 10 deg). With ``noise``:
    1 mm on the vehicle, 3 mm on the load, 0.5 deg on the attitude, 1 % on the thrust."""
    g, l, mu = PARAMS.gravity, PARAMS.cable_length, PARAMS.mass_load / TOTAL
    # the load's radius r_L: its specific force (-r_L rate^2 radial, g) along the cable
    r_load = radius
    for _ in range(100):
        angle = math.atan(r_load * rate**2 / g)
        r_load = radius + l * math.sin(angle)
    drop = l * math.cos(angle)
    radial = np.stack([np.cos(rate * t), np.sin(rate * t), 0 * t], axis=1)
    up = np.array([0.0, 0.0, 1.0])
    p = radius * radial + 1.5 * up
    p_load = r_load * radial + (1.5 - drop) * up
    a_c = -((1 - mu) * radius + mu * r_load) * rate**2 * radial + g * up
    b3 = a_c / np.linalg.norm(a_c, axis=1)[:, None]
    tilt = np.cross(up, b3)  # the shortest rotation from e3 to b3, then the heading
    half = 0.5 * np.arcsin(np.linalg.norm(tilt, axis=1))
    axis = tilt / np.linalg.norm(tilt, axis=1)[:, None]
    q_tilt = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * axis], axis=1)
    yaw = heading + math.radians(10) * np.sin(0.3 * t)
    q_yaw = np.stack([np.cos(yaw / 2), 0 * t, 0 * t, np.sin(yaw / 2)], axis=1)
    q = frames.quat_multiply(q_tilt, q_yaw)
    thrust = TOTAL * np.linalg.norm(a_c, axis=1)
    v = radius * rate * np.stack([-np.sin(rate * t), np.cos(rate * t), 0 * t], axis=1)
    if noise:
        rng = np.random.default_rng(seed)
        p = p + 0.001 * rng.standard_normal(p.shape)
        p_load = p_load + 0.003 * rng.standard_normal(p.shape)
        turn = np.concatenate([np.ones((len(t), 1)), 0.0044 * rng.standard_normal(p.shape)], 1)
        q = frames.quat_multiply(q, turn / np.linalg.norm(turn, axis=1)[:, None])
        thrust = thrust * (1 + 0.01 * rng.standard_normal(len(t)))
    return {
        "time": t,
        "p": p,
        "v": v,
        "attitude": q[:, [1, 2, 3, 0]],
        "p_load": p_load,
        "w_ref": np.stack([0 * t, 0 * t, 0.1 * np.cos(0.3 * t)], axis=1),
        "T_ref": thrust[:, None],
    }


def figures(a, params=PARAMS, **kw):
    q = a["attitude"][:, [3, 0, 1, 2]]
    checks = flight_checks(a["p"], q, a["p_load"], a["T_ref"], params, **kw)
    return {c.quantity: c for c in checks}


STEPS = 600  # 18 s at 30 ms


def test_accelerations_of_a_noisy_parabola():
    dt, t = 0.03, 0.03 * np.arange(200)
    p = np.stack([1.5 * t**2, 0 * t, -0.5 * 9.81 * t**2], axis=1)
    exact = accelerations(p, dt, 0.3)
    inside = np.isfinite(exact).all(axis=1)
    assert inside.sum() == 200 - 10 and np.allclose(exact[inside], [3.0, 0.0, -9.81])
    noisy = p + 0.003 * np.random.default_rng(0).standard_normal(p.shape)
    error = accelerations(noisy, dt, 0.3)[inside] - exact[inside]
    assert 0.2 < float(np.sqrt(np.mean(error**2))) < 1.0  # 3 mm of noise: about 0.5 m/s^2


def test_exact_and_noisy_flights_pass_with_their_figures():
    t = PARAMS.dt * np.arange(STEPS)
    exact = figures(circling(t, noise=False))
    assert exact[THRUST_AXIS].value < 0.5 and abs(exact[THRUST_SCALE].value - 1) < 0.005
    assert exact[CABLE_PULL].value < 0.5
    for seed in range(5):  # motion-capture and IMU-level noise, constants given or not
        for own in (True, False):
            found = figures(circling(t, seed=seed), own_cable=own)
            assert all(c.ok for c in found.values()), [c.text() for c in found.values()]
            assert found[THRUST_AXIS].value < 3 and found[CABLE_PULL].value < 3


def test_four_wrong_flights_are_refused_by_their_physics():
    t = PARAMS.dt * np.arange(STEPS)
    a = circling(t)
    swapped = dict(a, attitude=a["attitude"][:, [3, 0, 1, 2]])  # w-x-y-z read as x-y-z-w
    found = figures(swapped)
    assert found[UPRIGHT].ok  # heading near 180 deg: the older check saw nothing
    assert not found[THRUST_AXIS].ok and found[THRUST_AXIS].value > 15
    assert "another order" in found[THRUST_AXIS].cause
    c, r = (
        np.array([0.5, -0.3, 0.1]),
        frames.rotation_matrix(np.array([math.cos(0.3), 0, 0, math.sin(0.3)])),
    )
    moved = dict(a, p_load=(a["p_load"] - a["p"].mean(0)) @ r.T + a["p"].mean(0) + c)
    found = figures(moved, own_cable=False)  # no vehicle constants
    assert not found[CABLE_PULL].ok and "another frame" in found[CABLE_PULL].cause
    high = dict(a, T_ref=a["T_ref"] * HOVER / 0.3)  # hover throttle 0.3 for 0.5
    found = figures(high)
    assert found[THRUST].ok and not found[THRUST_SCALE].ok  # 1.67 x hover passed before
    assert found[THRUST_SCALE].value == pytest.approx(0.6, abs=0.03)
    assert "hover throttle" in found[THRUST_SCALE].cause


def flight_csv(tmp_path, arrays, name="flight", throttle=False):
    columns = default_columns(arrays)
    if throttle:
        columns["T_ref"] = columns["T_ref"] / (TOTAL * PARAMS.gravity) * HOVER
    return write_csv(tmp_path / f"{name}.csv", columns)


def refused(tmp_path, capsys, log, *extra):
    out = tmp_path / "ds"
    code = main(["import", str(log), "--out", str(out), "--quiet", *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"slungload import: error: {log}"), err
    assert not out.exists()
    return err[0]


def test_import_refuses_each_wrong_log_and_force_records_it(tmp_path, capsys):
    t = PARAMS.dt * np.arange(STEPS)
    a = circling(t)
    log = flight_csv(tmp_path, dict(a, attitude=a["attitude"][:, [3, 0, 1, 2]]), "swapped")
    line = refused(tmp_path, capsys, log, "--cable-length", "0.7")
    assert THRUST_AXIS in line and "likely the attitude" in line and "--force" in line
    c = np.array([0.6, 0.2, 0.0])
    log = flight_csv(tmp_path, dict(a, p_load=a["p_load"] + c), "moved")
    line = refused(tmp_path, capsys, log)  # no vehicle constants
    assert CABLE_PULL in line and "another frame" in line
    log = flight_csv(tmp_path, a, "throttle", throttle=True)
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps({"thrust": "normalized"}))
    line = refused(tmp_path, capsys, log, "--map", str(mapping), "--hover-throttle", "0.3")
    assert THRUST_SCALE in line and "--hover-throttle" in line
    out = tmp_path / "ds"
    code = main(["import", str(log), "--out", str(out), "--quiet", "--map", str(mapping),
                 "--hover-throttle", "0.3", "--force"])  # fmt: skip
    assert code == 0
    checks = json.loads((out / "vehicle.json").read_text())["import"]["checks"]
    assert checks["force"] and THRUST_SCALE in checks["forced"][0]
    assert checks["limits"]["thrust_scale"] == ConsistencyLimits().thrust_scale
    table = summarize(out).to_table()  # inspect shows the same figure, outside
    assert f"outside: {THRUST_SCALE}" in table
    capsys.readouterr()
    out = tmp_path / "good"
    log = flight_csv(tmp_path, a, "good", throttle=True)
    assert main(["import", str(log), "--out", str(out), "--quiet", "--map", str(mapping),
                 "--hover-throttle", str(HOVER)]) == 0  # fmt: skip
    assert "outside: " not in summarize(out).to_table()


def second_csv(path, t, arrays, shift=7.25, yaw=0.6, seed=1):
    """A motion-capture CSV of ``arrays`` (vehicle and load), 1 mm noise, its clock
    ``shift`` s behind and its frame turned by ``yaw`` rad and moved."""
    r = frames.rotation_matrix(np.array([math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)]))
    rng = np.random.default_rng(seed)

    def seen(p):
        return (p - [1.0, -2.0, 0.2]) @ r + 0.001 * rng.standard_normal(p.shape)

    p, p_load = seen(arrays["p"]), seen(arrays["p_load"])
    columns = {"time": t - shift, **{f"p_{x}": p[:, i] for i, x in enumerate("xyz")}}
    columns.update({f"p_load_{x}": p_load[:, i] for i, x in enumerate("xyz")})
    return write_csv(path, columns)


def wander(t):
    """A slow, smooth path: the circle flown again with the drift of a repeat, 2-5 cm."""
    return np.stack([0.03 * np.sin(0.4 * t + 1), 0.025 * np.cos(0.3 * t), 0.01 * np.sin(t)], 1)


def test_second_log_of_a_repeat_mission_is_refused_and_the_same_flight_accepted(tmp_path):
    t = PARAMS.dt * np.arange(STEPS)  # the log_files flight: its speed varies, to align on
    first = flight_csv(tmp_path, truth(t), "first")
    fine = np.arange(t[0] - 2, t[-1] + 2, 0.01)  # 100 Hz, running before and after
    same = second_csv(tmp_path / "same.csv", fine, truth(fine))
    result = import_logs([first], tmp_path / "a", params=PARAMS, progress=False,
                         second=SecondLog(same))  # fmt: skip
    record = json.loads((tmp_path / "a" / "vehicle.json").read_text())["import"]["logs"]
    found = record[str(first)]["second"]["alignment"]
    assert found["residual_m"] < 0.002 and 0.0005 < found["noise_floor_m"] < 0.003, found
    assert result.flights
    b = truth(fine)
    repeat = dict(b, p=b["p"] + wander(fine), p_load=b["p_load"] + wander(fine))
    again = second_csv(tmp_path / "repeat.csv", fine, repeat)
    with pytest.raises(
        ConsistencyError, match=rf"{re.escape(RESIDUAL)} = 0\.0[1-4].*repeat of the same"
    ):
        import_logs([first], tmp_path / "b", params=PARAMS, progress=False,
                    second=SecondLog(again))  # fmt: skip
    assert not (tmp_path / "b").exists()
    options = ImportOptions(limits=ConsistencyLimits(align_floor=0.05))  # --align-tolerance
    import_logs([first], tmp_path / "c", params=PARAMS, progress=False, options=options,
                second=SecondLog(again))  # fmt: skip


def test_noise_floor_of_a_track():
    t = 0.01 * np.arange(3000)
    p = np.stack([np.sin(t), np.cos(0.5 * t), 0.1 * t], axis=1)
    rng = np.random.default_rng(0)
    assert noise_floor(t, p, 0.1) < 1e-4
    noisy = p + 0.001 * rng.standard_normal(p.shape)  # sqrt(3) mm in 3-D
    assert noise_floor(t, noisy, 0.1) == pytest.approx(math.sqrt(3) * 0.001, rel=0.1)


def test_simulated_datasets_pass_every_check(tmp_path, capsys):
    pytest.importorskip("mujoco")
    runs = {
        "default": [],
        "excited": ["--excite", "1,0.5,0.5,0.2"],
        "loads": ["--load-mass", "0.05:0.5", "--vehicle-mass", "1.0:2.0", "--cable-length",
                  "0.4:1.2"],
    }  # fmt: skip
    for name, extra in runs.items():
        out = tmp_path / name
        args = ["simulate", "--out", str(out), "--flights", "3", "--workers", "1", "--quiet"]
        assert main([*args, "--seed", "5", *extra]) == 0
        table = summarize(out).to_table()
        for quantity in (THRUST_AXIS, THRUST_SCALE, CABLE_PULL):
            assert quantity in table
        assert "outside: " not in table, table


def test_physics_checks_skip_a_flight_too_short_to_differentiate():
    t = PARAMS.dt * np.arange(8)
    a = circling(t)
    q = a["attitude"][:, [3, 0, 1, 2]]
    assert physics_checks(a["p"], q, a["p_load"], a["T_ref"], PARAMS, dt=PARAMS.dt) == ()


def test_a_track_sparser_than_max_gap_names_it():
    slow, fast = np.arange(0.0, 20.0, 0.2), np.arange(0.0, 20.0, 0.01)  # 5 Hz and 100 Hz
    first = Stream("topic pose", slow, truth(slow)["p"])
    second = Stream("columns p_x, p_y, p_z", fast, truth(fast)["p"])
    with pytest.raises(LogError, match=r"topic pose has a sample every 0\.2 s .*--max-gap 0\.1"):
        align_tracks(first, second, max_gap=0.1)
    assert align_tracks(first, second, max_gap=0.25).residual < 0.01
