"""Property-based fuzzing of the safety gate on the simulated UR5, UR10e and ABB IRB 2600.

Thousands of random and adversarial commands go through the public robot API with the driver spied on;
every command that reaches the driver is re-checked by an independent dense checker
(:mod:`weldcell.testing.safety_fuzz`). Nothing unsafe may reach the driver and nothing but
``SafetyError`` may escape. Hypothesis runs derandomized (reproducible in CI).
"""

from __future__ import annotations

import numpy as np
import pytest
from weldcell.hal.kinematics import get_model
from weldcell.hal.robot import RobotMotionSettings
from weldcell.hal.safety import SafetyGate
from weldcell.hal.sim.devices import SimRobot
from weldcell.hal.sim.world import SimWorld
from weldcell.sdk.cell import SafetyLimits
from weldcell.testing.safety_fuzz import fuzz_robot

pytest.importorskip("hypothesis")

EXAMPLES = 50  # per robot and tool; docs/safety.md has the long run (benchmarks/safety_fuzz.py)


def sim_robot(model_name: str, tcp=(0.0, 0.0, 0.0)) -> SimRobot:
    """A simulated arm in a box that its home pose is well inside, with the table 0.3 m below the TCP."""
    model = get_model(model_name)
    p = model.fk(model.home)[:3, 3]
    R = model.reach
    limits = SafetyLimits(
        workspace_min=(-0.9 * R, -0.9 * R, p[2] - tcp[2] - 0.3),
        workspace_max=(1.1 * R, 0.9 * R, p[2] + 0.5),
    )
    r = SimRobot(
        model, SimWorld([]), gate=SafetyGate(limits, model=model), motion=RobotMotionSettings(tcp_xyz=tcp)
    )
    r.configure()
    r.activate()
    return r


@pytest.mark.parametrize("tcp", [(0.0, 0.0, 0.0), (0.03, 0.0, 0.2)], ids=["flange", "torch"])
@pytest.mark.parametrize("name", ["ur5", "ur10e", "abb-irb2600"])
def test_no_unsafe_command_reaches_the_driver(name, tcp):
    robot = sim_robot(name, tcp)

    def set_joints(q):
        robot.q = np.array(q, dtype=float)

    report = fuzz_robot(robot, EXAMPLES, vary_start=True, set_joints=set_joints)
    print(name, tcp, report.summary())
    assert report.errors == [], report.errors[:5]
    assert report.unsafe == [], report.unsafe[:5]
    accepted = sum(v for (k, o), v in report.counts.items() if o == "accepted")
    assert accepted >= 0.1 * EXAMPLES, f"the fuzzer must exercise accepted motions too: {report.summary()}"
