"""The machine's pressure advance (`machine.pressure_advance`): Klipper's smooth pressure advance, its K and the
smoothing time.

On a move that extrudes (e forward) while x or y moves, the extruder leads the nominal flow by K times its own
velocity: e_adv(t) = e(t) + K e'(t); the whole extruder position is then averaged over `smooth_time` with a
triangular weight (Klipper's klippy/chelper/kin_extruder.c), so the lead comes and goes smoothly. The host plans it
into the extruder's steps (codegen/motion/advance.py); the board plays tables as always. G-code `M900 K<k>`
(Marlin) and `M572 D0 S<k>` (RepRapFirmware) change K from their line on; the smoothing stays on while the job
has `pressure_advance`, with K 0 too (Klipper turns it off with K 0). Cartesian and corexy machines: a delta's
carriages are not yet cut from shaped motion, so it is refused at the key.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import AfterValidator, BeforeValidator, Field

from codegen.job.schema.fields import Model, fail, number_value

DEFAULT_SMOOTH_TIME = 0.04  # s, Klipper's pressure_advance_smooth_time
MAX_SMOOTH_TIME = 0.2  # s, Klipper's largest


def _smooth_time(v: float) -> float:
    if not 0.0 < v <= MAX_SMOOTH_TIME:
        raise fail("range", f"must be > 0 and <= {MAX_SMOOTH_TIME:g} (s, Klipper's range)")
    return v


class PressureAdvance(Model):
    """K (mm of filament per mm/s of extruder velocity, i.e. s) and the smoothing time (s), as Klipper's
    [extruder] pressure_advance and pressure_advance_smooth_time."""

    k: Annotated[float, BeforeValidator(number_value), Field(ge=0)]
    smooth_time: Annotated[float, BeforeValidator(number_value), AfterValidator(_smooth_time)] = DEFAULT_SMOOTH_TIME
