"""Every real G-code file of tests/data/gcode plans, and its tables pass the twin's checks, on both table
formats: the AVR's and the compact stream of the 8051 (curve timing, runs across blocks).

(special-fields.gcode carries a deliberately wrong checksum: tests/test_gcode_reader.py.)"""

from pathlib import Path

import pytest

from codegen.job import load_job
from codegen.pipeline import host_build

DATA = Path(__file__).resolve().parent / "data" / "gcode"
MACHINE = """
name: {name}
target: {target}
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
    y: {{steps_per_mm: 80, max_velocity: 200, max_accel: 3000}}
    z: {{steps_per_mm: 400, max_velocity: 12, max_accel: 400}}
{extruder}program:
  gcode: {gcode}
"""
EXTRUDER = "    e: {steps_per_mm: 100, max_velocity: 80, max_accel: 5000}\n"
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
    job = tmp_path / "job.yaml"
    job.write_text(MACHINE.format(name=Path(name).stem, target=target, extruder=EXTRUDER if FILES[name] else "",
                                  gcode=DATA / name))
    host = host_build(load_job(job))
    assert host.findings.ok, host.findings.problems
    assert host.findings.final == host.findings.expected_final
    assert host.plan.total > 0 and host.schedule.n_blocks > 0
