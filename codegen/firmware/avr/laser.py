"""The ATmega2560's laser PWM (codegen/tables/laser.py): Timer5 in phase-correct PWM with TOP in ICR5, the laser on one of
its compare outputs. The step interrupt (templates/avr/player_isr.S.j2) latches each power record's counts with
the run it comes before and writes them to the compare register right after that run's first STEP edge (with feed
hold, M4's scaled by the feed factor there and after every dilated event: codegen/tables/laser.py follow);
laser.h (templates/avr/laser.h.j2) sets the timer up and turns the laser off at every stop."""

from __future__ import annotations

from codegen.errors import BuildError
from codegen.firmware.avr.player import PRESCALERS
from codegen.firmware.config import FirmwareConfig

# The pins Timer5 drives (the only 16-bit timer nothing else uses: Timer1 is the player's, Timer3 the heaters'
# period, Timer4 the bed's PWM) and their channels; OC5A (PL3) is RAMPS's Z STEP.
LASER_CHANNELS = {"PL4": "B", "PL5": "C"}
OCR_ADDRESS = {"B": 0x12A, "C": 0x12C}  # data-space addresses of OCR5BL and OCR5CL (the high byte follows)
LASER_TOP_ADDRESS = 0x126  # ICR5L's: Timer5's TOP, the PWM's period (the high byte follows)
LASER_VARIABLES = 3  # bytes of SRAM: the latched counts (u16) and whether they wait for the next event (u8)
LASER_HOLD_VARIABLES = 4  # beside feed hold: the counts in force (u16) and a spill of two registers


def laser_ocr_address(pin: str) -> int:
    """The data-space address of the laser's compare register (its low byte)."""
    return OCR_ADDRESS[LASER_CHANNELS[pin]]


def laser_context(config: FirmwareConfig) -> dict:
    """The templates' `laser` (None without one)."""
    laser = config.laser
    if laser is None:
        return {"laser": None}
    if laser.pin not in LASER_CHANNELS:
        raise BuildError(f"board {config.board}: laser_pwm {laser.pin} is not a Timer5 output "
                         f"({', '.join(LASER_CHANNELS)})")
    channel = LASER_CHANNELS[laser.pin]
    clock = PRESCALERS[laser.prescaler].replace("CS1", "CS5")
    return {"laser": {"pin": laser.pin, "port": laser.pin[1], "bit": int(laser.pin[2]), "channel": channel,
                      "ocr": f"OCR5{channel}", "com": f"COM5{channel}1", "top": laser.top,
                      "prescaler": laser.prescaler, "clock": clock, "pwm_hz": f"{laser.pwm_hz:g}",
                      "actual_hz": f"{laser.actual_hz:.1f}"}}
