"""The one-step demo (test/helpers/driver_harness.py): a voltage step through the driver node
over DDS reaches the model's steady state. (`make demo`, the whole session, is
test_session_bringup's and test_identification_node's.)"""

from __future__ import annotations

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

pytest.importorskip("rclpy")


def test_step_demo_reaches_the_model_steady_state_and_stops_the_driver_cleanly(ros_domain):
    from helpers.driver_harness import run_step_demo

    lines: list[str] = []
    res = run_step_demo(volts=10.0, step_s=1.5, domain_id=ros_domain, out=lines.append)
    assert res.driver_exit == 0
    assert "motor safe" in res.driver_final_line
    # seed 000 at 10 V: ~139.8 rad/s and ~0.54 A with its Coulomb friction (noise-averaged)
    assert res.steady_speed_rad_s == pytest.approx(res.predicted_speed_rad_s, rel=5e-3)
    assert res.steady_current_a == pytest.approx(res.predicted_current_a, abs=0.01)
    assert res.predicted_speed_rad_s == pytest.approx(139.0, rel=0.02)
    assert any(line.startswith("steady state") for line in lines)
    assert res.t_s[-1] > 1.4  # the whole step arrived


def test_demo_reports_a_driver_that_cannot_start_in_one_line(ros_domain):
    from helpers.driver_harness import run_step_demo

    from pmdc_ident.core.errors import PmdcError

    with pytest.raises(PmdcError, match=r"exited at start \(status 2\): .*rate_hz.*out of range"):
        run_step_demo(rate_hz=50000.0, domain_id=ros_domain, out=lambda _line: None)
