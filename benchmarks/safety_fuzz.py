"""Fuzz the safety gate of the simulated UR5, UR10e and ABB IRB 2600 (flange and 20 cm torch) and time the
refusal of far/non-finite targets. Numbers go into docs/safety.md.

    .venv/bin/python benchmarks/safety_fuzz.py --examples 1000
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from weldcell.sdk.errors import SafetyError
from weldcell.testing.safety_fuzz import fuzz_robot

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "hal"))
from test_safety_fuzz import sim_robot  # noqa: E402


def refusal_time(robot, T, repeat: int = 200) -> float:
    """Median wall time (s) of a refused move_linear to ``T``."""
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        try:
            robot.move_linear(T)
        except SafetyError:
            pass
        else:  # pragma: no cover
            raise AssertionError("accepted")
        out.append(time.perf_counter() - t)
    return float(np.median(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=1000, help="commands per robot and tool")
    args = ap.parse_args()
    print(
        "| robot | tool | commands | accepted (linear / joint / servo / path) | refused | unsafe | "
        "non-gate exceptions | time |"
    )
    print("|---|---|---|---|---|---|---|---|")
    total_unsafe = 0
    for name in ("ur5", "ur10e", "abb-irb2600"):
        for tool, tcp in (("flange", (0.0, 0.0, 0.0)), ("torch 20 cm", (0.03, 0.0, 0.2))):
            robot = sim_robot(name, tcp)

            def set_joints(q, robot=robot):
                robot.q = np.array(q, dtype=float)

            t = time.perf_counter()
            rep = fuzz_robot(robot, args.examples, vary_start=True, set_joints=set_joints)
            dt = time.perf_counter() - t
            c = rep.counts
            acc = [c[(k, "accepted")] for k in ("linear", "joint", "servo", "path")]
            ref = sum(v for (k, o), v in c.items() if o == "refused")
            split = " / ".join(map(str, acc))
            print(
                f"| {name} | {tool} | {sum(acc) + ref} | {sum(acc)} ({split}) | {ref} | "
                f"{len(rep.unsafe)} | {len(rep.errors)} | {dt:.0f} s |"
            )
            total_unsafe += len(rep.unsafe) + len(rep.errors)
            for line in rep.unsafe[:5] + rep.errors[:5]:
                print("   ", line)
    robot = sim_robot("ur5")
    T0 = robot.state().T_base_tcp
    for what, T in (
        ("target 1e5 m away", T0 + np.pad(np.array([[1e5], [0], [0]]), ((0, 1), (3, 0)))),
        ("target 1e6 m away", T0 + np.pad(np.array([[1e6], [0], [0]]), ((0, 1), (3, 0)))),
        ("pose with inf", np.where(np.eye(4) > 0, np.inf, T0)),
    ):
        print(f"refusal of a {what}: {refusal_time(robot, T) * 1e6:.0f} us (median of 200)")
    sys.exit(1 if total_unsafe else 0)


if __name__ == "__main__":
    main()
