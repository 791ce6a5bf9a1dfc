"""G4 P0 (and S0) waits no time but for the moves to finish, as Marlin, Grbl and Klipper do, and so does Marlin's
M400: the plan comes to rest there. Found by benchmarks/klipper_steps.py: `G1 X20 F6000 / G4 P0 / G1 X40` passed X20 at 100 mm/s."""

from __future__ import annotations

import numpy as np

from codegen.job import load_job
from codegen.pipeline.host import host_build
from codegen.toolpath.items import Dwell
from codegen.toolpath.segments import WAIT_REST_S
from tests.gcode.helpers import items

JOB = """name: rest
target: avr
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: 80, max_velocity: 200, max_accel: 2000}}
    y: {{steps_per_mm: 80, max_velocity: 200, max_accel: 2000}}
program:
  gcode: |
    G1 X20 F6000
    {rest}
    G1 X40
"""


def test_g4_p0_s0_and_m400_are_rests():
    got = items("G4 P0\nG4 S0\nG4 P0.5\nM400\n", dialect="marlin")
    assert [(type(d), d.seconds) for d in got] == [(Dwell, WAIT_REST_S), (Dwell, WAIT_REST_S), (Dwell, 0.0005),
                                                   (Dwell, WAIT_REST_S)]


def test_g4_p0_and_m400_bring_the_machine_to_rest_where_a_comment_does_not(tmp_path):
    exits = []
    for rest in ("G4 P0", "M400", "; nothing"):
        path = tmp_path / "rest.yaml"
        path.write_text(JOB.format(rest=rest))
        host = host_build(load_job(path))
        first = np.flatnonzero(host.plan.length > 0)[0]
        exits.append(float(host.plan.v_exit[first]))
    assert exits[:2] == [0.0, 0.0] and exits[2] > 50.0
