"""PX4 logs from before 1.13: a scalar ``thrust`` in ``vehicle_rates_setpoint`` (as in pyulog's
sample logs), or the thrust only in ``actuator_controls_0`` (``control[3]``), detected or
mapped. Each log is written by ``log_files.write_ulog`` and rewritten by pyulog's own writer
(``ULog.write_ulog``), so the file read is pyulog's."""

from __future__ import annotations

import numpy as np
import pytest
from log_files import HOVER, PARAMS, THRUST_PER_THROTTLE, imported, px4_topics, write_ulog

from slungload.data.importing import ImportOptions, import_logs
from slungload.data.readers.logs import LogError

LOAD_TOPIC = {"load": "vehicle_mocap_odometry:1"}
RATES = ("vehicle_rates_setpoint", 0)
THRUST = ("vehicle_thrust_setpoint", 0)


def old_log(tmp_path, change, name="old.ulg"):
    """The truth flight's PX4 topics at 100 Hz, ``change(topics)`` applied, written and then
    rewritten by pyulog."""
    from pyulog import ULog

    us = {k: np.arange(0, 3_000_000, 10_000) for k in
          ("position", "attitude", "rates", "thrust", "load")}  # fmt: skip
    topics = px4_topics(us)
    change(topics)
    first = write_ulog(tmp_path / f"mine_{name}", topics, {"MPC_THR_HOVER": HOVER})
    log = ULog(str(first))
    out = tmp_path / name
    log.write_ulog(str(out))
    return out


def throttle(topics):
    """The normalised throttle, positive up, of the thrust set-point."""
    return -np.asarray(topics[THRUST]["xyz[2]"])


def scalar_thrust(topics):  # PX4 before 1.13: vehicle_rates_setpoint.thrust, no thrust topic
    topics[RATES]["thrust"] = throttle(topics)
    del topics[THRUST]


def actuator_controls(topics):  # only the mixer's input holds the thrust
    t = topics[THRUST]["timestamp"]
    controls = {f"control[{i}]": np.zeros(len(t)) for i in range(8)}
    controls["control[3]"] = throttle(topics)
    topics[("actuator_controls_0", 0)] = {"timestamp": t, **controls}
    del topics[THRUST]


def run(log, out, mapping=None):
    return import_logs([log], out, params=PARAMS, mapping={**LOAD_TOPIC, **(mapping or {})},
                       options=ImportOptions(split="train"), progress=False)  # fmt: skip


@pytest.mark.parametrize(
    ("change", "field", "topic"),
    [(scalar_thrust, "thrust", "vehicle_rates_setpoint:0"),
     (actuator_controls, "control[3]", "actuator_controls_0:0")],
)  # fmt: skip
def test_an_older_px4_log_imports_with_its_thrust_detected(tmp_path, change, field, topic):
    log = old_log(tmp_path, change)
    got = run(log, tmp_path / "ds")
    note = [n for n in got.notes if "thrust from" in n]
    assert note and f"thrust from {field} of topic {topic}" in note[0], got.notes
    flight = imported(tmp_path / "ds")["old"]
    whole = {k: np.arange(0, 3_000_000, 10_000) for k in
             ("position", "attitude", "rates", "thrust", "load")}  # fmt: skip
    truth_t = px4_topics(whole)[THRUST]
    # the throttle held at the grid, in newtons by MPC_THR_HOVER
    i = np.searchsorted(truth_t["timestamp"] * 1e-6, flight["time"] + 1e-6, side="right") - 1
    expected = -truth_t["xyz[2]"][i] * THRUST_PER_THROTTLE
    assert np.abs(flight["T_ref"][:, 0] - expected).max() < 1e-3


def test_a_mapping_names_the_scalar_thrust_of_the_rates_set_point(tmp_path):
    def both(topics):  # a thrust topic of zeros beside the rates set-point's scalar thrust
        topics[RATES]["thrust"] = throttle(topics)
        topics[THRUST]["xyz[2]"] = 0 * topics[THRUST]["xyz[2]"]

    log = old_log(tmp_path, both)
    with pytest.raises(Exception, match=r"thrust / hover thrust"):  # zeros: refused by checks
        run(log, tmp_path / "a")
    got = run(log, tmp_path / "b", {"thrust": "vehicle_rates_setpoint"})
    assert not any("thrust from" in n for n in got.notes)  # mapped: no note
    flight = imported(tmp_path / "b")["old"]
    assert np.abs(flight["T_ref"][:, 0] / (PARAMS.mass_quad + PARAMS.mass_load)
                  / PARAMS.gravity - 1).max() < 0.05  # fmt: skip


def test_a_log_without_any_thrust_names_the_topic(tmp_path):
    log = old_log(tmp_path, lambda topics: topics.pop(THRUST))
    with pytest.raises(LogError, match=r"no topic 'vehicle_thrust_setpoint' \(mapping key "
                       r"'thrust'\); the log has: .*vehicle_rates_setpoint:0"):  # fmt: skip
        run(log, tmp_path / "a")
