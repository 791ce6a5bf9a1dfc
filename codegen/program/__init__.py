"""The job's program as a stream of toolpath items (shapes or G-code), its homing and heater commands."""
