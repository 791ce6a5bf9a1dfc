"""The host side of the heaters: thermistors and the ADC table (sensors), the integer control laws the firmware
mirrors (control), the thermal plant and its closed-loop simulation (plant), relay auto-tuning (tuning), thermal
protection (protection), a job's heaters with their defaults (settings), and a program's heater settings as the
flash image plays them (program).

Everything that goes to the firmware is an integer: deci-degrees (0.1 degC), ADC readings, control periods of
control.PID_PERIOD_S, fixed-point gains.
"""
