"""Calibration prints, as Klipper's and Marlin's users make them: G-code whose setting changes along the print at
known places, and a table of which place has which value (`printer-codegen calibrate`, codegen/cli/calibrate.py).

layout.py places a pattern on the machine and writes its G-code; ringing.py is the ringing tower (M593 F per band
of height, or per band of a plotted pattern on a machine without an extruder); pressure_advance.py the pressure
advance pattern (M900 K per line). Each returns a Calibration: the G-code and its bands.
"""

from codegen.calibrate.layout import Band, Calibration
from codegen.calibrate.pressure_advance import PressureAdvanceTest, pressure_advance_pattern
from codegen.calibrate.ringing import RingingTest, ringing_test

__all__ = ["Band", "Calibration", "PressureAdvanceTest", "RingingTest", "pressure_advance_pattern", "ringing_test"]
