"""Physical consistency checks at import and in ``inspect`` (``data/consistency.py``).

Every case is a small CSV log of the ``truth`` flight (``log_files``) spoiled the way a real
log is: positions in two frames, the load on the vehicle's columns, quaternion columns in
w-x-y-z order, time in milliseconds, a throttle read as newtons. Each is refused with exit
status 2, one line naming the file, the quantity, the value and the likely cause, and nothing
written; ``--force`` imports it and records that in ``vehicle.json``.
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
from slungload.config import VehicleParams
from slungload.data.consistency import (
    CABLE,
    CABLE_OFF,
    NORM,
    SPREAD,
    STEP,
    SWING,
    THRUST,
    UPRIGHT,
    ConsistencyError,
    ConsistencyLimits,
    flight_checks,
)
from slungload.data.importing import ImportOptions, import_logs
from slungload.data.summary import summarize


def flight_csv(tmp_path, name="flight", steps=120, spoil=None):
    """A CSV log of the truth flight at the dataset's step, ``spoil(columns)`` applied."""
    columns = default_columns(truth(PARAMS.dt * np.arange(steps)))
    if spoil is not None:
        spoil(columns)
    return write_csv(tmp_path / f"{name}.csv", columns)


def cli_import(tmp_path, log, *extra):
    out = tmp_path / "ds"
    code = main(["import", str(log), "--out", str(out), "--quiet", *extra])
    return code, out


def load_in_ned_with_offset(c):  # the public CSV: the load in another frame and origin
    x, y, z = c["p_load_x"].copy(), c["p_load_y"].copy(), c["p_load_z"].copy()
    c["p_load_x"], c["p_load_y"], c["p_load_z"] = y + 0.3, x - 0.2, -z + 0.1


def load_above(c):  # the load's z-down height read as z up
    c["p_load_z"] = 2 * c["p_z"] - c["p_load_z"]


def load_on_vehicle(c):
    for a in "xyz":
        c[f"p_load_{a}"] = c[f"p_{a}"].copy()


def quaternion_wxyz(c):
    q = np.stack([c[f"attitude_{a}"] for a in "xyzw"], axis=1)
    for i, a in enumerate("xyzw"):
        c[f"attitude_{a}"] = q[:, [3, 0, 1, 2]][:, i]


def quaternion_doubled(c):
    for a in "xyzw":
        c[f"attitude_{a}"] = 2 * c[f"attitude_{a}"]


def throttle_as_newtons(c):
    c["T_ref"] = c["T_ref"] / 30.0  # a throttle about 0.47


def milliseconds(c):
    c["time"] = 1000 * c["time"]


REFUSED = {
    "load in another frame": (load_in_ned_with_offset, [CABLE_OFF, SPREAD, "different frames"]),
    "load above the vehicle": (load_above, [SWING, "NED", "world"]),
    "load on the vehicle's columns": (load_on_vehicle, [CABLE, "vehicle's own topic"]),
    "w-x-y-z order": (quaternion_wxyz, [UPRIGHT, "w-x-y-z in x-y-z-w columns"]),
    "quaternion not unit": (quaternion_doubled, [NORM, "not a unit quaternion"]),
    "throttle read as newtons": (throttle_as_newtons, [THRUST, "normalised throttle"]),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_inconsistent_log_is_refused_by_name_and_nothing_written(tmp_path, capsys, case):
    spoil, words = REFUSED[case]
    log = flight_csv(tmp_path, spoil=spoil)
    code, out = cli_import(tmp_path, log, "--cable-length", str(PARAMS.cable_length))
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f"slungload import: error: {log}"), err
    for word in [*words, "likely", "--force"]:
        assert word in err[0], (word, err[0])
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == [log.name]


def test_force_imports_and_records_it(tmp_path, capsys):
    log = flight_csv(tmp_path, spoil=load_in_ned_with_offset)
    code, out = cli_import(tmp_path, log, "--force")
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "note: forced: " in captured.out and SPREAD in captured.out
    checks = json.loads((out / "vehicle.json").read_text())["import"]["checks"]
    assert checks["force"] is True and len(checks["forced"]) == 1
    assert checks["figures"]["flight"][SPREAD] > 0.25
    assert checks["limits"]["cable_spread"] == ConsistencyLimits().cable_spread
    table = summarize(out).to_table()  # inspect names the flight outside the check
    assert "outside: " in table and "flight" in table.split("outside: ")[1]


def test_consistent_log_passes_and_inspect_shows_the_figures(tmp_path, capsys):
    log = flight_csv(tmp_path)
    code, out = cli_import(tmp_path, log, "--cable-length", "0.7")
    assert code == 0, capsys.readouterr().err
    checks = json.loads((out / "vehicle.json").read_text())["import"]["checks"]
    assert checks["force"] is False and checks["forced"] == []
    assert checks["cable_reference"] == "vehicle constants"
    figures = checks["figures"]["flight"]
    assert abs(figures[CABLE] - 0.7) < 1e-3 and abs(figures[CABLE_OFF]) < 1e-3
    assert figures[SWING] < 5.0  # a conical swing at 17 deg averages to near straight down
    assert figures[UPRIGHT] > 0.9 and abs(figures[THRUST] - 1.0) < 0.01
    assert main(["inspect", str(out)]) == 0
    shown = capsys.readouterr().out
    for quantity in (CABLE, CABLE_OFF, SPREAD, SWING, UPRIGHT, THRUST):
        assert quantity in shown
    assert "outside: " not in shown


def test_cable_length_against_the_constants_or_only_its_spread(tmp_path):
    log = flight_csv(tmp_path)  # a 0.7 m cable
    with pytest.raises(ConsistencyError, match=r"median \|pL - p\| - l \(m\) = -0\.5.*l = 1\.2 m"):
        import_logs([log], tmp_path / "a", params=VehicleParams(cable_length=1.2), progress=False)
    result = import_logs([log], tmp_path / "b", params=None, progress=False)  # no constants
    assert any("checked only for its spread" in n for n in result.notes)
    checks = json.loads((tmp_path / "b" / "vehicle.json").read_text())["import"]["checks"]
    assert (
        checks["cable_reference"] == "own median" and CABLE_OFF not in checks["figures"]["flight"]
    )


def test_time_in_milliseconds_is_detected_or_refused_when_stated_wrong(tmp_path):
    log = flight_csv(tmp_path, spoil=milliseconds)
    result = import_logs([log], tmp_path / "ms", params=PARAMS, progress=False)
    assert any("read as ms" in n and "time_unit" in n for n in result.notes)
    assert result.flights == {"flight": 120}
    with pytest.raises(
        ConsistencyError, match=rf"columns p_x, p_y, p_z: {re.escape(STEP)} = 30 .*time_unit"
    ):
        import_logs([log], tmp_path / "s", params=PARAMS, mapping={"time_unit": "s"},
                    progress=False)  # fmt: skip


def test_hover_throttle_too_low_is_a_thrust_above_hover(tmp_path):
    def throttle(c):
        c["T_ref"] = c["T_ref"] / 30.0

    log = flight_csv(tmp_path, spoil=throttle)
    mapping = {"thrust": "normalized"}
    options = ImportOptions(hover_throttle=0.1)  # the real one is about 0.47
    with pytest.raises(ConsistencyError, match=r"thrust / hover thrust \(-\) = 4\.7.*--hover-thr"):
        import_logs([log], tmp_path / "a", params=PARAMS, mapping=mapping, options=options,
                    progress=False)  # fmt: skip
    options = ImportOptions(newtons_per_throttle=30.0)
    import_logs([log], tmp_path / "b", params=PARAMS, mapping=mapping, options=options,
                progress=False)  # fmt: skip
    vehicle = json.loads((tmp_path / "b" / "vehicle.json").read_text())
    assert vehicle["import"]["logs"][str(log)]["newtons_per_throttle"] == 30.0


def test_flight_checks_on_known_figures():
    t = PARAMS.dt * np.arange(200)
    a = truth(t)
    q = a["attitude"][:, [3, 0, 1, 2]]
    ok = flight_checks(a["p"], q, a["p_load"], a["T_ref"], PARAMS)
    assert all(c.ok for c in ok), [c.text() for c in ok if not c.ok]
    above = a["p"] + (a["p"] - a["p_load"])  # the load mirrored above the vehicle
    swing = {c.quantity: c for c in flight_checks(a["p"], q, above, a["T_ref"], PARAMS)}[SWING]
    assert not swing.ok and swing.value > 170 and "NED" in swing.cause
    frd = frames.quat_multiply(q, np.array([0.0, 1.0, 0.0, 0.0]))  # FRD read as FLU
    upright = {c.quantity: c for c in flight_checks(a["p"], frd, a["p_load"], a["T_ref"], PARAMS)}
    assert not upright[UPRIGHT].ok and "FRD body read as FLU" in upright[UPRIGHT].cause
    pitch = frames.quat_multiply(q, np.array([0.0, 0.0, 1.0, 0.0]))  # pitched 180 deg
    upright = {c.quantity: c for c in flight_checks(a["p"], pitch, a["p_load"], a["T_ref"], PARAMS)}
    assert not upright[UPRIGHT].ok and "frames" in upright[UPRIGHT].cause
    limits = ConsistencyLimits(mean_swing=math.radians(170))
    assert {c.quantity: c for c in flight_checks(a["p"], q, above, a["T_ref"], PARAMS, limits)}[
        SWING
    ].ok is (swing.value <= 170)
    with pytest.raises(ValueError, match="lower limit"):
        ConsistencyLimits(thrust_low=3.0)
