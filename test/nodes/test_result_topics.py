"""Typed, plottable results and the /diagnostics naming scheme, without DDS (issue 24)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pmdc_ident.core.enums import LogLevel
from pmdc_ident.core.motors import load_motor
from pmdc_ident.node_logic.drift_monitor import DriftMonitor
from pmdc_ident.nodes.result_topics import (
    DRIFT_FIELDS,
    PARAMETER_FIELDS,
    array_message,
    drift_topics,
    parameter_topics,
    topic_token,
)
from pmdc_ident.process.diagnostics import LevelLog, hardware_id, status_name

DOC = {
    "schema_version": 1,
    "parameters": {
        "R": {"value": 1.375, "ci95": [1.37, 1.38], "unit": "ohm", "identifiable": True,
              "stderr": 0.0025},
        "L": {"value": 3e-4, "ci95": None, "unit": "H", "identifiable": False,
              "stderr": None},
        "coulomb_friction.torque_nm": {"value": 0.025, "ci95": [0.024, 0.026], "unit": "N*m",
                                       "identifiable": True, "stderr": 5e-4},
    },
}  # fmt: skip


def test_every_parameter_gets_a_labelled_array_topic_of_its_own():
    topics = {t.topic: t for t in parameter_topics(DOC)}
    assert set(topics) == {
        "identified_parameters/R",
        "identified_parameters/L",
        "identified_parameters/coulomb_friction/torque_nm",
    }
    r = topics["identified_parameters/R"]
    assert r.values == (1.375, 1.37, 1.38, 0.0025, 1.0)
    assert r.label == "R [ohm]: " + ",".join(PARAMETER_FIELDS)
    lo = topics["identified_parameters/L"].values
    assert lo[0] == 3e-4 and all(math.isnan(x) for x in lo[1:4]) and lo[4] == 0.0
    msg = array_message(r)
    assert list(msg.data) == list(r.values)
    (dim,) = msg.layout.dim
    assert (dim.label, dim.size, dim.stride) == (r.label, 5, 5)


def test_drift_reports_become_one_array_per_quantity():
    spec = load_motor("seed000_ebike")
    t = np.arange(500) * 1e-3
    (report, *_) = DriftMonitor(spec).process(
        t, np.full(t.size, 6.0), np.full(t.size, 0.6), np.full(t.size, 80.0)
    )
    topics = {x.topic: x for x in drift_topics(report)}
    assert set(topics) == {
        "model_drift/resistance",
        "model_drift/back_emf",
        "model_drift/friction",
        "model_drift/delay",
        "model_drift/temperature_rise",
    }
    r = report.quantity("resistance")
    est, lo, hi, ref, level = topics["model_drift/resistance"].values
    assert (est, ref, level) == (r.value, spec.model.params.R, float(r.level))
    assert lo == pytest.approx(r.value - r.ci95) and hi == pytest.approx(r.value + r.ci95)
    assert topics["model_drift/back_emf"].label == "back_emf [V*s/rad]: " + ",".join(DRIFT_FIELDS)


@pytest.mark.parametrize(
    ("name", "token"),
    [("R", "R"), ("coulomb_friction.torque_nm", "coulomb_friction/torque_nm"),
     ("cogging.1st", "cogging/_1st"), ("a-b", "a_b")],
)  # fmt: skip
def test_names_become_valid_topic_tokens(name, token):
    assert topic_token(name) == token


def test_one_status_naming_scheme_and_a_hardware_id_per_motor():
    assert status_name("/left_wheel/driver_node", "motor driver") == (
        "left_wheel/driver_node: motor driver"
    )
    assert status_name("/monitor_node", "motor drift") == "monitor_node: motor drift"
    assert hardware_id("/left_wheel") == "pmdc_motor/left_wheel" != hardware_id("/right_wheel")
    assert hardware_id("/") == "pmdc_motor" and hardware_id("/x", "SN-0042") == "SN-0042"


def test_level_changes_are_said_once():
    log = LevelLog("motor drift")
    assert log.update(0, "fine") is None  # starting OK is not news
    assert log.update(0, "fine") is None
    assert log.update(1, "resistance WARN") == (
        LogLevel.WARNING,
        "motor drift: OK -> WARN: resistance WARN",
    )
    assert log.update(1, "resistance WARN") is None
    assert log.update(3, "no samples") == (
        LogLevel.WARNING,
        "motor drift: WARN -> STALE: no samples",
    )
    assert log.update(0, "back") == (LogLevel.INFO, "motor drift: STALE -> OK: back")
    assert LevelLog("x").update(3, "no samples yet") == (
        LogLevel.INFO,
        "x: start -> STALE: no samples yet",
    )
    driver = LevelLog("driver status", causes_logged=True)  # each cause has its own line
    assert driver.update(0, "running") is None
    assert driver.update(2, "over-current: ...") == (LogLevel.INFO, "driver status: OK -> ERROR")


def test_a_node_logs_each_level_at_its_own_severity_and_a_plain_string_as_an_error():
    from pmdc_ident.nodes.runtime import log

    said: list[tuple[str, str]] = []

    class Logger:
        def __getattr__(self, severity: str):  # type: ignore[no-untyped-def]
            return lambda text: said.append((severity, text))

    class Node:
        def get_logger(self) -> Logger:
            return Logger()

    for level in LogLevel:
        log(Node(), level, f"a {level.value} line")  # type: ignore[arg-type]
    assert said == [
        ("info", "a info line"),
        ("warning", "a warning line"),
        ("error", "a error line"),
    ]
    said.clear()
    log(Node(), "info", "a string is not a level")  # type: ignore[arg-type]
    assert said == [("error", "a string is not a level [log level 'info' is not a LogLevel]")]
