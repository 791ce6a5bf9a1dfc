"""Firmware per target: a FirmwareConfig and a Schedule rendered into C sources, built, measured for fit."""
