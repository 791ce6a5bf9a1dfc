"""The machine's input shaper (`machine.input_shaper`): per axis, Klipper's shaper, the resonance it cancels and its
damping ratio; `max_smoothing` bounds how far shaping may take the tool from the unshaped motion.

The host shapes the planned motion before the motors' transform (codegen/motion/shaped_motion.py), so the tables
carry shaped steps. The shapers' formulas are in codegen/motion/shapers.py; their names and the damping each
accepts (where Singhose's fits of the EI family still hold) are the job's contract and live here.
"""

from __future__ import annotations

from typing import Annotated, Optional

from pydantic import AfterValidator, BeforeValidator, Field, model_validator

from codegen.job.schema.fields import Model, Positive, choice, fail, number_value

# Klipper's shaper names, each with the largest damping ratio its formulas accept.
SHAPER_MAX_DAMPING = {"zv": 0.99, "mzv": 0.99, "zvd": 0.99, "ei": 0.4, "2hump_ei": 0.3, "3hump_ei": 0.2}
SHAPED_AXES = ("x", "y", "z")
SHAPER_HZ = (1.0, 1000.0)  # the frequencies a shaper may have (job key and G-code M593 alike)
DEFAULT_SHAPER_DAMPING = 0.1  # Klipper's default damping ratio


def _frequency(v: float) -> float:
    if not SHAPER_HZ[0] <= v <= SHAPER_HZ[1]:  # a frame's resonance: Klipper's calibration sweeps 5 to 200 Hz
        raise fail("range", "must be >= 1 and <= 1000 (Hz: below 1 Hz a shaper lasts seconds, above 1000 Hz it "
                            "spans less than the player's step)")
    return v


class AxisShaper(Model):
    """One axis's shaper, as Klipper's [input_shaper] gives it (shaper_type_x, shaper_freq_x, damping_ratio_x)."""

    type: choice(*SHAPER_MAX_DAMPING)  # type: ignore[valid-type]
    freq: Annotated[float, BeforeValidator(number_value), AfterValidator(_frequency)]  # Hz
    damping: Annotated[float, BeforeValidator(number_value), Field(ge=0)] = DEFAULT_SHAPER_DAMPING

    @model_validator(mode="after")
    def _damping_within_the_fit(self) -> "AxisShaper":
        largest = SHAPER_MAX_DAMPING[self.type]
        if self.damping > largest:
            raise fail("range", f"must be <= {largest:g} for {self.type} (its formulas hold up to there)",
                       at=("damping",))
        return self


class InputShaper(Model):
    """Shapers for x, y and optionally z (an axis without one moves unshaped), and the smoothing allowed."""

    x: Optional[AxisShaper] = None
    y: Optional[AxisShaper] = None
    z: Optional[AxisShaper] = None
    max_smoothing: Optional[Positive] = None  # mm; None: reported, never a failure

    @property
    def axes(self) -> dict[str, AxisShaper]:
        """The shaped axes by name, in x, y, z order."""
        return {name: getattr(self, name) for name in SHAPED_AXES if getattr(self, name) is not None}
