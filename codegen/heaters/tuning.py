"""M303-style relay auto-tuning, split the way the tune firmware and the host split it: the relay itself
(`RelayLoop`, which templates/avr/tune.c.j2 mirrors in integers, one step per control period) and the host's
arithmetic on what it reports (`Relay`: Marlin's bias adjustment and the cycles' figures). `relay_test` runs both
against the Python plant: the reference the firmware's tune (printer-codegen tune) is compared with.

The relay follows Marlin's PID_autotune: the heater runs at `bias + d` until the reading rises above the target
(after at least RELAY_MIN_DWELL_S of heating), then at `bias - d` until it falls below the target (after at least
RELAY_MIN_DWELL_S of cooling). At every new heating phase after the first, the bias moves towards balancing the
heating and cooling times: `bias += d * (t_high - t_low) / (t_high + t_low)` (C's division, truncating towards
zero), limited to [20, max - 20], and `d = min(bias, max - 1 - bias)`. Each full cycle gives the relay's high/low
duties, the extremes of the readings and the period.

At each switch the relay reports a `Switch`: the period it happened in, the phase that ended and its length, and
the extreme reading since the previous switch of the same kind: the highest since the last end of heating when
heating ends (the peak comes after the heater went low), the lowest since the last end of cooling when cooling
ends.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from codegen.heaters.control import PID_PERIOD_S, PWM_MAX, gains_from_relay
from codegen.heaters.plant import Plant
from codegen.heaters.sensors import SensorSpec, adc_reading, adc_temperature_table

RELAY_MIN_DWELL_S = 5.0  # Marlin's 5000 ms between relay switches
BIAS_MARGIN = 20  # Marlin's LIMIT(bias, 20, max_pow - 20)


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


@dataclass(frozen=True)
class Switch:
    """A relay switch as the firmware reports it (periods of PID_PERIOD_S, deci-degrees)."""

    period: int  # the control period it switched in, from 0 at the start
    heating: bool  # the phase that begins: True when a cooling phase ended
    length: int  # periods of the phase that ended
    extreme_dc: int  # heating ended: the highest reading since the last end of heating; cooling ended: the lowest


def marlin_bias(bias: int, d: int, t_high: int, t_low: int, max_duty: int = PWM_MAX) -> tuple[int, int]:
    """Marlin's next (bias, d) after a cycle that heated t_high and cooled t_low (any one unit of time)."""
    num, den = d * (t_high - t_low), t_low + t_high
    step = abs(num) // den * (1 if num >= 0 else -1)  # C's long division truncates towards zero
    bias = min(max(bias + step, BIAS_MARGIN), max_duty - BIAS_MARGIN)
    return bias, (bias if bias <= max_duty // 2 else max_duty - 1 - bias)


@dataclass
class RelayLoop:
    """The relay's state and step, as the tune firmware runs it (integers; `step` once per control period)."""

    target_dc: int
    bias: int
    d: int
    dwell: int = round(RELAY_MIN_DWELL_S / PID_PERIOD_S)
    heating: bool = True
    period: int = 0
    switched_on: int = 0
    switched_off: int = 0
    t_max: int = 0
    t_min: int = 0

    def __post_init__(self):
        self.t_max = self.t_min = self.target_dc

    @property
    def duty(self) -> int:
        return self.bias + self.d if self.heating else self.bias - self.d

    def step(self, t: int) -> Optional[Switch]:
        """The reading `t` of this period; the switch it makes, if any (self.duty is then the new phase's)."""
        k, switch = self.period, None
        self.period += 1
        self.t_max, self.t_min = max(self.t_max, t), min(self.t_min, t)
        if self.heating and t > self.target_dc and k - self.switched_on >= self.dwell:
            switch = Switch(k, False, k - self.switched_on, self.t_max)
            self.heating, self.switched_off, self.t_max = False, k, self.target_dc
        elif not self.heating and t < self.target_dc and k - self.switched_off >= self.dwell:
            switch = Switch(k, True, k - self.switched_off, self.t_min)
            self.heating, self.switched_on, self.t_min = True, k, self.target_dc
        return switch


@dataclass
class Relay:
    """The host's half: it follows the switches, keeps the cycles, and says the next (bias, d) at each cycle."""

    max_duty: int = PWM_MAX
    period_s: float = PID_PERIOD_S
    bias: int = field(init=False)
    d: int = field(init=False)
    cycles: list[RelayCycle] = field(default_factory=list)
    heatings: int = 0  # heating phases begun after the heat-up from ambient
    t_high: int = 0
    last_max: int = 0

    def __post_init__(self):
        self.bias = self.d = self.max_duty // 2

    def switch(self, s: Switch) -> Optional[tuple[int, int]]:
        """Take a reported switch; at the start of a heating phase (after the first), the new (bias, d)."""
        if not s.heating:
            self.t_high, self.last_max = s.length, s.extreme_dc
            return None
        self.heatings += 1
        if self.heatings == 1:  # the lowest reading since the heat-up began is ambient's: no cycle yet
            return None
        self.cycles.append(RelayCycle(self.bias + self.d, self.bias - self.d, self.last_max / 10, s.extreme_dc / 10,
                                      (self.t_high + s.length) * self.period_s))
        self.bias, self.d = marlin_bias(self.bias, self.d, self.t_high, s.length, self.max_duty)
        return self.bias, self.d


def relay_test(plant: Plant, sensor: SensorSpec, target_c: float, cycles: int = 5, max_duty: int = PWM_MAX,
               pullup_ohm: float = 4700.0, period_s: float = PID_PERIOD_S, limit_s: float = 1800.0) -> RelayCycle:
    """Run the relay on the plant from ambient until `cycles` full cycles; the last one's figures."""
    table = adc_temperature_table(sensor, pullup_ohm)
    host = Relay(max_duty, period_s)
    loop = RelayLoop(round(target_c * 10), host.bias, host.d, round(RELAY_MIN_DWELL_S / period_s))
    temp = plant.ambient_c
    for _ in range(round(limit_s / period_s)):
        switch = loop.step(int(table[int(adc_reading(sensor, temp, pullup_ohm))]))
        if switch is not None:
            update = host.switch(switch)
            if len(host.cycles) >= cycles:
                return host.cycles[-1]
            if update is not None:
                loop.bias, loop.d = update
        temp = plant.advance(temp, loop.duty, period_s)
    raise ValueError(f"no relay oscillation around {target_c:g} degC within {limit_s:g} s")
