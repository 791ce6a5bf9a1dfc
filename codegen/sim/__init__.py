"""Simulator runners, one per target: run the exact firmware image and decode its pins (avr: simavr, mcs51: s51),
with keys, thermal plants and the link beside it."""
