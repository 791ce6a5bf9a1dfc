"""Simulator runners, one per target: run the exact firmware image and decode its pins (avr: simavr)."""
