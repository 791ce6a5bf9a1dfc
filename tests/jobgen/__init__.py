"""Random job files for the property tests (hypothesis): machines of every kinematics (machines.py) and programs
of every shape kind (shapes.py) and of G-code (gcode.py), written as YAML text so that the real loader reads them.

The invariant (`outcome`, outcome.py): a job the loader accepts either builds with every check passing
(findings.ok, final == expected_final, and verify's second reading of its G-code finds the tables doing what it
says), or is refused with a positioned error (JobError, exit 2: every diagnostic has file:line:col) or a size
error (exit 1: the tables do not fit the chip, as `build` refuses them). Anything else (a failed check, a
BuildError not about size, any other exception) raises `Bug`.
"""

from tests.jobgen.outcome import Bug, jobs, message_class, outcome

TARGETS = ("avr", "mcs51")
KINEMATICS = ("cartesian", "corexy", "delta")

__all__ = ["KINEMATICS", "TARGETS", "Bug", "jobs", "message_class", "outcome"]
