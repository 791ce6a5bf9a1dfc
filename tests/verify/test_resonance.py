"""The toolhead on a spring (codegen/verify/resonance.py) against closed forms: its response to a step of the
commanded position, and its lag behind a constant acceleration; and verify's --resonance option."""

from __future__ import annotations

import math

import numpy as np
import pytest

from codegen.verify.resonance import AxisResonance, Oscillator, resonance_option


@pytest.mark.parametrize("freq, damping", [(48.0, 0.1), (30.0, 0.0), (120.0, 0.5)])
def test_a_step_of_the_command_rings_as_the_closed_form(freq, damping):
    """u jumps by 1 mm at t0: x(t) = 1 - exp(-zeta w t) (cos w_d t - zeta w / w_d sin w_d t) (the step response of
    (2 zeta w s + w^2) / (s^2 + 2 zeta w s + w^2)), over 40 s: the chunked sums keep their precision."""
    oscillator = Oscillator(AxisResonance(0, freq, damping), level=0.0)
    t0 = 0.25
    oscillator.play(np.array([t0]), np.array([1.0]))
    t = t0 + np.linspace(0.0, 40.0, 20_001)
    rest = np.zeros_like(t)
    x = 1.0 + oscillator.ringing(t, rest, rest, rest).real  # at rest the ringing is about the motors' position
    omega = 2 * math.pi * freq
    omega_d = omega * math.sqrt(1 - damping**2)
    tau = t - t0
    expected = 1 - np.exp(-damping * omega * tau) * (np.cos(omega_d * tau)
                                                     - damping * omega / omega_d * np.sin(omega_d * tau))
    assert np.abs(x - expected).max() < 1e-9


def test_many_steps_in_chunks_equal_one_step_each():
    """10,000 steps over 30 s played at once (chunked sums) or a chunk at a time end in the same state."""
    rng = np.random.default_rng(7)
    times = np.sort(rng.uniform(0, 30, 10_000))
    steps = rng.choice([-0.0125, 0.0125], 10_000)
    whole, parts = (Oscillator(AxisResonance(0, 40.0, 0.2), 0.0) for _ in range(2))
    whole.play(times, steps)
    for chunk in np.array_split(np.arange(10_000), 7):
        parts.play(times[chunk], steps[chunk])
    assert whole.level == pytest.approx(parts.level, abs=1e-12)
    assert abs(whole.state - parts.state) < 1e-12


def test_constant_acceleration_leaves_a_lag_of_a_over_w_squared_and_no_ringing():
    """Steps of 1/400 mm at the half-step crossings of u = a t^2 / 2: once the start's ringing has decayed, the
    toolhead trails u by a / w^2 and the ringing about that (the particular part taken out) is below a step's
    forced response."""
    spm, accel, freq, damping = 400.0, 2000.0, 40.0, 0.15
    steps = np.arange(1, 410_000)
    times = np.sqrt(2 * (steps - 0.5) / spm / accel)  # step k when u crosses (k - 1/2) / spm
    oscillator = Oscillator(AxisResonance(0, freq, damping), 0.0)
    oscillator.play(times, np.full(len(times), 1 / spm))
    t = np.linspace(0.8, 1.0, 201)  # 20 decay times after the start
    u, du, ddu = accel * t**2 / 2, accel * t, np.full_like(t, accel)
    z = oscillator.ringing(t, u, du, ddu)
    assert np.abs(z).max() < 0.05 / spm
    level = np.floor(u * spm + 0.5) / spm  # the staircase there
    lag = -accel / (2 * math.pi * freq) ** 2
    x_minus_u = z.real + lag  # Re z is the vibration about u + lag
    toolhead = x_minus_u + u
    assert np.all(np.abs(toolhead - level - lag) <= 0.5 / spm + 0.05 / spm)


def test_the_resonance_option():
    assert resonance_option("x=48,0.1") == AxisResonance(0, 48.0, 0.1)
    assert resonance_option("Y=52") == AxisResonance(1, 52.0, 0.1)
    for bad in ("x48", "w=48", "x=-3", "x=48,1.5", "x=fast"):
        with pytest.raises(ValueError):
            resonance_option(bad)
