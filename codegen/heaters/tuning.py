"""M303-style relay auto-tuning against the Python plant: what the firmware's relay test measures, and the gains
the host makes of it (control.gains_from_relay).

The relay follows Marlin's PID_autotune: the heater runs at `bias + d` until the reading rises above the target
(after at least RELAY_MIN_DWELL_S of heating), then at `bias - d` until it falls below the target (after at least
RELAY_MIN_DWELL_S of cooling). At every new heating phase after the first, the bias moves towards balancing the
heating and cooling times: `bias += d * (t_high - t_low) / (t_high + t_low)`, limited to [20, max - 20], and
`d = min(bias, max - 1 - bias)`. The last full cycle gives the relay's high/low duties, the extremes of the
readings and the period.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codegen.heaters.control import PID_PERIOD_S, PWM_MAX, gains_from_relay
from codegen.heaters.plant import Plant
from codegen.heaters.sensors import SensorSpec, adc_reading, adc_temperature_table

RELAY_MIN_DWELL_S = 5.0  # Marlin's 5000 ms between relay switches


@dataclass(frozen=True)
class RelayCycle:
    """One relay oscillation: duties 0..255, reading extremes in degC, period in seconds."""

    high_duty: int
    low_duty: int
    t_max_c: float
    t_min_c: float
    period_s: float

    def gains(self) -> tuple[float, float, float]:
        """Ziegler-Nichols (kp, ki, kd) of this oscillation."""
        return gains_from_relay(self.high_duty, self.low_duty, self.t_max_c, self.t_min_c, self.period_s)


def relay_test(plant: Plant, sensor: SensorSpec, target_c: float, cycles: int = 5, max_duty: int = PWM_MAX,
               pullup_ohm: float = 4700.0, period_s: float = PID_PERIOD_S, limit_s: float = 1800.0) -> RelayCycle:
    """Run the relay on the plant from ambient until `cycles` full cycles; the last one's figures."""
    table = adc_temperature_table(sensor, pullup_ohm)
    target_dc = round(target_c * 10)
    dwell = round(RELAY_MIN_DWELL_S / period_s)
    bias = d = max_duty // 2
    heating, duty = True, bias + d
    switched_on = switched_off = 0  # the periods of the last switches
    t_high = t_low = 0
    t_max = t_min = target_dc
    done = 0
    temp = plant.ambient_c
    for k in range(round(limit_s / period_s)):
        t = int(table[int(adc_reading(sensor, temp, pullup_ohm))])
        t_max, t_min = max(t_max, t), min(t_min, t)
        if heating and t > target_dc and k - switched_on >= dwell:
            heating, duty = False, bias - d
            switched_off, t_high = k, k - switched_on
            last_max, t_max = t_max, target_dc
        elif not heating and t < target_dc and k - switched_off >= dwell:
            heating = True
            switched_on, t_low = k, k - switched_off
            if done > 0:
                cycle = RelayCycle(bias + d, bias - d, last_max / 10, t_min / 10, (t_high + t_low) * period_s)
                bias = int(np.clip(bias + (d * (t_high - t_low)) // (t_low + t_high), 20, max_duty - 20))
                d = bias if bias <= max_duty // 2 else max_duty - 1 - bias
                if done >= cycles:
                    return cycle
            duty, t_min = bias + d, target_dc
            done += 1
        temp = plant.advance(temp, duty, period_s)
    raise ValueError(f"no relay oscillation around {target_c:g} degC within {limit_s:g} s")
