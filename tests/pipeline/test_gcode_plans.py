"""Every real G-code file of tests/data/gcode plans, and its tables pass the twin's checks, on both targets
(the AVR's clock and the 8051's).

(special-fields.gcode carries a deliberately wrong checksum: tests/gcode/test_reader.py.)"""

import pytest

from codegen.job import load_job
from codegen.pipeline.host import host_build
from tests.helpers import gcode_job_file

FILES = {  # file -> does the machine need an extruder
    "grbl-cam.gcode": False,
    "parser/circle.gcode": False,
    "parser/circle-inch.gcode": False,
    "parser/spaces.gcode": False,
    "plotter/circular_interpolation.gcode": False,
    "plotter/shapes.gcode": False,
    "plotter/smooth_curves_circular_interpolation.gcode": False,
    "laser/hiking.gcode": False,
    "slicer/benchy-arcs-arcwelder.gcode": True,
    "slicer/benchy-prusaslicer.gcode": True,
    "slicer/puzzle-cura.gcode": True,
}


@pytest.mark.parametrize("target", ["avr", "mcs51"])
@pytest.mark.parametrize("name", sorted(FILES))
def test_every_file_plans_with_passing_checks(name, target, tmp_path):
    host = host_build(load_job(gcode_job_file(tmp_path, name, target, extruder=FILES[name])))
    assert host.findings.ok, host.findings.problems
    assert host.findings.final == host.findings.expected_final
    assert host.plan.total > 0 and host.schedule.n_blocks > 0
