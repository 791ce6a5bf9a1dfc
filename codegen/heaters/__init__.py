"""The host side of the heaters: thermistors and the ADC table (sensors), the integer control laws the firmware
mirrors (control), the thermal plant and its closed-loop simulation (plant), relay auto-tuning (tuning) and thermal
protection (protection). A job's heaters with their defaults are codegen/program/heater_settings.py's, and a
program's heater commands codegen/program/heaters.py's.

Everything that goes to the firmware is an integer: deci-degrees (0.1 degC), ADC readings, control periods of
control.PID_PERIOD_S, fixed-point gains.
"""
