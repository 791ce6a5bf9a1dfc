"""The host side of the heaters: thermistor tables, the integer control laws, the Python plant with the board's
default gains, relay tuning, thermal protection, and the job's `heaters:` section."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

from codegen.errors import JobError
from codegen.heaters.control import (D_FILTER_SHIFT, DEFAULT_CONTROL, INT32_MAX, PID_FUNCTIONAL_RANGE_DC, PID_PERIOD_S,
                                     FixedBangBang, FixedPid, _worst_sum, bang_bang, fixed_bang_bang, fixed_control,
                                     fixed_gains, gains_from_relay, pid_reference)
from codegen.heaters.plant import DEFAULT_PLANTS, Plant, heating_figures, simulate
from codegen.heaters.protection import DEFAULT_PROTECTION, REASONS, first_trip, fixed_protection
from codegen.heaters.sensors import (THERMISTORS, adc_reading, adc_temperature_table, millivolts, resistance_ohm,
                                     sensor_limits, temperature_c)
from codegen.heaters.tuning import relay_test
from codegen.job import load_job
from codegen.program.heater_settings import heater_settings
from tests.helpers import DATA

EPCOS = "EPCOS 100K B57560G104F"
HOTEND, BED = DEFAULT_PLANTS["hotend"], DEFAULT_PLANTS["bed"]

# Marlin's thermistor_1.h (type 1, EPCOS 100k): (10-bit reading, degC) with the reading 1023 * R / (R + 4.7k).
MARLIN_TYPE_1 = [
    (23, 300), (25, 295), (27, 290), (28, 285), (31, 280), (33, 275), (35, 270), (38, 265), (41, 260), (44, 255),
    (48, 250), (52, 245), (56, 240), (61, 235), (66, 230), (71, 225), (78, 220), (84, 215), (92, 210), (100, 205),
    (109, 200), (120, 195), (131, 190), (143, 185), (156, 180), (171, 175), (187, 170), (205, 165), (224, 160),
    (245, 155), (268, 150), (293, 145), (320, 140), (348, 135), (379, 130), (411, 125), (445, 120), (480, 115),
    (516, 110), (553, 105), (591, 100), (628, 95), (665, 90), (702, 85), (737, 80), (770, 75), (801, 70),
    (830, 65), (857, 60), (881, 55), (903, 50), (922, 45), (939, 40), (954, 35), (966, 30), (977, 25), (985, 20),
    (993, 15), (999, 10), (1004, 5), (1008, 0),
]


# ---- sensors ----

def test_epcos_matches_marlins_table_within_1_percent_plus_one_adc_step():
    adc, temp = np.array(MARLIN_TYPE_1, dtype=float).T
    marlin_r = 4700.0 * adc / (1023.0 - adc)
    quantization = 0.5 * (1.0 / adc + 1.0 / (1023.0 - adc))  # relative R of half a reading
    error = np.abs(resistance_ohm(EPCOS, temp) / marlin_r - 1.0)
    assert np.all(error <= 0.01 + quantization)
    assert resistance_ohm(EPCOS, 25.0) == pytest.approx(100_000, rel=0.01)  # datasheet R25 = 100k +-1 %


def test_beta_3950_and_custom_sensors():
    r100 = 100_000 * math.exp(3950 * (1 / 373.15 - 1 / 298.15))
    assert resistance_ohm("Generic 3950", [25.0, 100.0]) == pytest.approx([100_000, r100])
    assert resistance_ohm({"beta": 3950, "r25_ohm": 100_000}, 100.0) == pytest.approx(r100)
    sh = THERMISTORS[EPCOS]
    assert resistance_ohm({"steinhart_hart": [sh.a, sh.b, sh.c]}, 210.0) == pytest.approx(resistance_ohm(EPCOS, 210))
    temps = np.linspace(-40, 500, 55)
    for name in THERMISTORS:
        assert temperature_c(name, resistance_ohm(name, temps)) == pytest.approx(temps, abs=1e-9)


@pytest.mark.parametrize("name", list(THERMISTORS))
def test_adc_table_is_int16_monotonic_and_reads_back_the_temperature(name):
    table = adc_temperature_table(name)
    assert table.dtype == np.int16 and table.shape == (1024,)
    assert np.all(np.diff(table.astype(int)) < 0)  # an NTC: hotter at lower readings
    temps = np.arange(0.0, 300.0, 0.5)
    readings = adc_reading(name, temps)
    step = (table[readings - 1].astype(int) - table[readings + 1]) / 20  # one reading's width in degC
    assert np.all(np.abs(table[readings] / 10 - temps) <= step)
    assert table[977] == pytest.approx(250, abs=5) if name == EPCOS else True  # Marlin: 977 is 25 degC


def test_millivolts_feed_the_adc_the_same_reading():
    temps = np.arange(-40.0, 501.0)
    mv = millivolts(EPCOS, temps)
    assert np.all(np.diff(mv) < 0) and mv[0] < 5000 and mv[-1] > 0
    assert np.array_equal(np.minimum(np.floor(mv * 1024 / 5000), 1023).astype(int), adc_reading(EPCOS, temps))


@pytest.mark.parametrize("name", list(THERMISTORS))
def test_open_and_short_limits(name):
    limits, table = sensor_limits(name), adc_temperature_table(name)
    assert table[limits.adc_open] < -200 <= table[limits.adc_open - 1]  # the first reading colder than -20 degC
    assert table[limits.adc_short] > 4000 >= table[limits.adc_short + 1]  # the last reading hotter than 400 degC
    assert limits.adc_open <= 1023 and limits.adc_short >= 0  # an open wire reads 1023, a short 0
    working = adc_reading(name, np.arange(0.0, 351.0))
    assert np.all((working > limits.adc_short) & (working < limits.adc_open))


# ---- control laws ----

def float_pid(kp: float, ki: float, kd: float, temps, target: int, max_power: float = 1.0) -> np.ndarray:
    """The PID in floating point with the same structure, for the fixed-point round trip."""
    top, integral, derivative, previous, out = round(255 * max_power), 0.0, 0.0, None, []
    for t in temps:
        e = target - t
        if previous is None:
            previous = t
        integral = min(max(integral + ki * PID_PERIOD_S / 10 * e, 0.0), top)
        derivative += (kd / (PID_PERIOD_S * 10) * (previous - t) - derivative) / 2**D_FILTER_SHIFT
        previous = t
        out.append(min(max(math.floor(kp / 10 * e + integral + derivative), 0), top))
    return np.array(out)


@pytest.mark.parametrize("gains", [(35.0, 2.5, 80.0), (22.2, 1.08, 114.0), (8.0, 0.3, 5.0)])
def test_fixed_point_pid_equals_a_float_pid_within_one_lsb(gains):
    rng = np.random.default_rng(7)
    k = np.arange(3000)
    temps = 2100 + np.round(40 * np.sin(k / 150) + rng.integers(-3, 4, k.size)).astype(int)  # inside the range
    fixed = fixed_gains(*gains, max_power=0.9)
    duties = pid_reference(fixed, temps, 2100)
    assert np.count_nonzero((duties > 0) & (duties < fixed.max_duty)) > 300  # the linear range is exercised
    assert np.abs(duties - float_pid(*gains, temps, 2100, max_power=0.9)).max() <= 1


def test_fixed_gains_use_the_largest_shift_that_fits_int32():
    fixed = fixed_gains(*DEFAULT_CONTROL["hotend"]["pid"].values())
    assert _worst_sum(fixed.kp_q, fixed.ki_q, fixed.kd_q, fixed.i_max) <= INT32_MAX
    doubled = (2 * fixed.kp_q, 2 * fixed.ki_q, 2 * fixed.kd_q, 2 * fixed.i_max)
    assert _worst_sum(*doubled) > INT32_MAX  # one more bit would overflow
    assert fixed.i_max == 255 << fixed.shift and fixed.max_duty == 255


def test_gains_that_cannot_be_represented_are_clear_errors():
    with pytest.raises(ValueError, match="overflow int32"):
        fixed_gains(1e9, 1.0, 1.0)
    with pytest.raises(ValueError, match="ki=1e-09 is too small"):
        fixed_gains(2000.0, 1e-9, 0.0)
    with pytest.raises(ValueError, match=">= 0"):
        fixed_gains(-1.0, 1.0, 1.0)
    with pytest.raises(ValueError, match="max_power"):
        fixed_gains(10.0, 1.0, 1.0, max_power=1.2)


def test_pid_outside_its_range_and_off():
    fixed = fixed_gains(35.0, 2.5, 80.0, max_power=0.5)
    r = PID_FUNCTIONAL_RANGE_DC
    temps = [2100 - r - 1, 2100 - r, 2100, 2100 + r + 1, 2100, 2100]
    duties = pid_reference(fixed, temps, 2100)
    assert duties[0] == 128 and duties[3] == 0  # full (max_power) below the range, nothing above
    assert duties[1] == 128  # at the range's edge P alone saturates: 35 * 10 degC > 128
    assert duties[4] == 0  # back in the range: I and D start again from 0, and e = 0
    assert list(pid_reference(fixed, [250, 2100], 0)) == [0, 0]  # target 0: off


def test_bang_bang_is_a_watermark():
    fixed = fixed_bang_bang(1.0)
    assert fixed == FixedBangBang(hysteresis_dc=10, max_duty=255)
    temps = [500, 589, 595, 605, 611, 605, 595, 589, 595]
    assert list(bang_bang(fixed, temps, 600)) == [255, 255, 255, 255, 0, 0, 0, 255, 255]
    assert list(bang_bang(fixed, [500], 0)) == [0]
    assert isinstance(fixed_control(DEFAULT_CONTROL["bed"]), FixedBangBang)
    assert isinstance(fixed_control(DEFAULT_CONTROL["hotend"]), FixedPid)


# ---- the plant with the board's defaults ----

def test_default_hotend_25_to_210_overshoots_little_and_holds_within_1_degree():
    sim = simulate(HOTEND, fixed_control(DEFAULT_CONTROL["hotend"]), 300, EPCOS, 210)
    fig = heating_figures(sim, 210)
    assert fig.overshoot_c < 0.5  # 0.10 degC
    assert fig.band_c < 0.5  # 0.09 degC from 30 s after reaching 209 degC
    assert 85 < fig.time_to_target_s < 95  # 88.9 s; full power alone: 81 s
    assert np.abs(sim.temp_c[-600:] - 210).max() < 1.0  # the last minute


def test_default_hotend_gains_suit_plants_half_to_twice_the_default():
    fixed = fixed_control(DEFAULT_CONTROL["hotend"])
    for capacity in (6.0, 12.0, 24.0):
        for loss in (0.084, 0.12, 0.168):
            for watts in (30.0, 40.0, 60.0):
                plant = Plant(capacity, loss, watts)
                if plant.steady_c() < 235:
                    continue  # cannot reach 210 degC with margin
                fig = heating_figures(simulate(plant, fixed, 400, EPCOS, 210), 210)
                assert fig.overshoot_c <= 1.5 and fig.band_c <= 1.0, (plant, fig)  # worst: 1.34 / 0.75


def test_without_the_derivative_filter_the_adc_steps_keep_the_hotend_below_its_target(monkeypatch):
    import codegen.heaters.control

    monkeypatch.setattr(codegen.heaters.control, "D_FILTER_SHIFT", 0)  # D = kd_q * (t_prev - t)
    sim = simulate(HOTEND, fixed_control(DEFAULT_CONTROL["hotend"]), 300, EPCOS, 210)
    assert heating_figures(sim, 210).time_to_target_s is None and sim.temp_c[-600:].max() < 205  # 203.7
    assert set(sim.duty[-600:]) == {0, 255}


def test_default_bed_reaches_60_and_holds():
    sim = simulate(BED, fixed_control(DEFAULT_CONTROL["bed"]), 600, EPCOS, 60)
    fig = heating_figures(sim, 60)
    assert 95 < fig.time_to_target_s < 115  # 104 s
    assert fig.overshoot_c < 1.0 and fig.band_c < 1.0  # 0.57 / 0.64 degC
    assert np.count_nonzero(np.diff(sim.duty)) < 100  # the MOSFET switches every few seconds, not every period


def test_default_heat_ups_never_trip_the_protection():
    for name, target, seconds in (("hotend", 210, 300), ("bed", 60, 600)):
        settings = heater_settings_default(name)
        sim = simulate(settings.plant, settings.fixed_control(), seconds, EPCOS, target)
        assert first_trip(settings.fixed_protection(), sim.adc, sim.reading_dc, target * 10) == (None, None)


# ---- relay tuning ----

def test_relay_formula_on_a_known_case():
    kp, ki, kd = gains_from_relay(255, 0, 212.0, 208.0, 20.0)
    ku = 4 * 127.5 / (math.pi * 2.0)
    assert (kp, ki, kd) == pytest.approx((0.6 * ku, 2 * 0.6 * ku / 20, 0.6 * ku * 20 / 8))
    with pytest.raises(ValueError):
        gains_from_relay(255, 0, 208.0, 212.0, 20.0)


def test_relay_tuned_gains_meet_the_overshoot_spec_on_the_plant():
    cycle = relay_test(HOTEND, EPCOS, 210)
    assert cycle.t_min_c < 210 < cycle.t_max_c and cycle.period_s >= 10  # Marlin's 5 s dwell each way
    kp, ki, kd = cycle.gains()  # about 21.9, 4.4, 27.4
    fig = heating_figures(simulate(HOTEND, fixed_gains(kp, ki, kd), 300, EPCOS, 210), 210)
    assert fig.overshoot_c <= 3.0 and fig.band_c <= 1.0  # 1.35 / 0.06 degC


# ---- protection ----

def hotend_guard():
    return fixed_protection(DEFAULT_PROTECTION["hotend"], 5.0, 275.0, sensor_limits(EPCOS))


def trip(temps, targets, adcs=None):
    fixed = hotend_guard()
    temps = np.asarray(temps)
    adcs = np.full(temps.shape, 500) if adcs is None else adcs
    return first_trip(fixed, adcs, temps, targets)


def test_protection_constants_are_marlins_in_periods():
    fixed = hotend_guard()
    assert (fixed.watch_periods, fixed.watch_increase_dc, fixed.watch_margin_dc) == (200, 20, 60)
    assert (fixed.runaway_periods, fixed.runaway_hysteresis_dc) == (400, 40)
    bed = DEFAULT_PROTECTION["bed"]
    assert (bed.watch_period_s, bed.watch_increase_c, bed.runaway_period_s, bed.runaway_hysteresis_c) == (60, 2, 20, 2)


def test_each_reason_at_its_period():
    limits = sensor_limits(EPCOS)
    n = 1000
    assert trip([250] * n, 2100, adcs=np.r_[[500] * 10, [limits.adc_open] * (n - 10)]) == ("sensor_open", 10)
    assert trip([250] * n, 0, adcs=np.r_[[500] * 10, [limits.adc_short] * (n - 10)]) == ("sensor_short", 10)
    assert trip([250] * n, 0, adcs=np.full(n, 1023)) == (None, None)  # an idle heater's input may be open
    assert trip([250] * 5 + [40] * 5, 2100) == ("min_temp", 5)
    assert trip([2000] * 5 + [2751] * 5, 0) == ("max_temp", 5)  # even with the heater off
    # heating: the target is set at period 3, nothing rises, and 20 s (200 periods) later it fails
    assert trip([250] * n, [0] * 3 + [2100] * (n - 3)) == ("heating_failed", 203)
    # 1.9 degC in each 20 s is not enough; 2 degC is, and the watch restarts
    assert trip(250 + np.arange(n) * 19 // 200, 2100) == ("heating_failed", 200)
    assert trip(250 + np.arange(n) // 10, 2100) == (None, None)
    # holding: reached 210 at period 10, 4.1 degC below from period 50: 40 s (400 periods) later, a runaway
    holding = np.r_[np.linspace(2050, 2100, 11).astype(int), [2100] * 39, [2059] * 600]
    assert trip(holding, 2100) == ("thermal_runaway", 450)
    assert trip(np.r_[holding[:50], [2060] * 600], 2100) == (None, None)  # exactly 4 degC below is allowed
    assert {"min_temp", "max_temp", "sensor_open", "sensor_short", "heating_failed", "thermal_runaway"} == set(REASONS)


def test_a_new_target_restarts_the_watches():
    # holding 210, then 220: no runaway until 220 is reached, but a watch (12 degC to go > 6 degC margin)
    temps = np.r_[[2100] * 100, [2100] * 400]
    targets = np.r_[[2100] * 100, [2220] * 400]
    assert trip(temps, targets) == ("heating_failed", 300)


# ---- the job's heaters ----

JOB = """\
machine:
  kinematics: cartesian
  steppers:
    x: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
    y: {steps_per_mm: 80, max_velocity: 200, max_accel: 3000}
"""
PROGRAM = """\
program:
  shapes:
    - line: {to: [10, 0]}
"""


def write(tmp_path: Path, heaters: str) -> Path:
    path = tmp_path / "job.yaml"
    path.write_text(JOB + textwrap.indent(textwrap.dedent(heaters), "  ") + PROGRAM)
    return path


def errors(path: Path) -> list[tuple[int, int, str]]:
    with pytest.raises(JobError) as info:
        load_job(path)
    return [(d.where.line, d.where.col, d.message) for d in info.value.diagnostics]


def heater_settings_default(name: str):
    return heater_settings(load_job(DATA / "jobs" / "good.yaml"))[name]


def test_bad_sensor_name_and_max_power_out_of_range(tmp_path):
    path = write(tmp_path, """\
      heaters:
        hotend: {sensor: epcos 100k, max_power: 1.5}
        bed: {sensor: Generic 3590}
    """)
    presets = "presets are 'EPCOS 100K B57560G104F', 'Generic 3950'"
    assert errors(path) == [
        (7, 22, "machine.heaters.hotend.sensor: unknown thermistor 'epcos 100k' "
                f"(did you mean 'EPCOS 100K B57560G104F'?); {presets}"),
        (7, 45, "machine.heaters.hotend.max_power: must be <= 1"),
        (8, 19, f"machine.heaters.bed.sensor: unknown thermistor 'Generic 3590' (did you mean 'Generic 3950'?); "
                f"{presets}"),
    ]


def test_heater_section_errors(tmp_path):
    path = write(tmp_path, """\
      heaters:
        hotnd: {}
        hotend:
          sensor: {beta: 3950}
          control: {pid: {kp: 1e9, ki: 1, kd: 1}}
        bed:
          control: {bang_bang: {hysteresis_c: 1}, pid: {kp: 1, ki: 0, kd: 0}}
          min_temp_c: 130
          plant: {heater_W: 100}
    """)
    assert errors(path) == [
        (7, 5, "machine.heaters: unknown heater 'hotnd' (did you mean 'hotend'?)"),
        (9, 15, "machine.heaters.hotend.sensor: expected either {beta, r25_ohm} or {steinhart_hart: [a, b, c]}"),
        (12, 16, "machine.heaters.bed.control: give either 'pid' or 'bang_bang'"),
        (13, 19, "machine.heaters.bed.min_temp_c: min_temp_c (130) must be below max_temp_c (125)"),
        (14, 15, "machine.heaters.bed.plant: unknown key 'heater_W' (did you mean 'heater_w'?)"),
    ]
    path = write(tmp_path, """\
      heaters:
        hotend: {control: {pid: {kp: 1e9, ki: 1, kd: 1}}}
    """)
    assert errors(path) == [(7, 29, "machine.heaters.hotend.control.pid: PID gains kp=1e+09 ki=1 kd=1 overflow "
                                    "int32 even unscaled")]


def test_no_heaters_section_gets_the_boards_defaults():
    settings = heater_settings(load_job(DATA / "jobs" / "good.yaml"))
    assert list(settings) == ["hotend", "bed"] and all(h.board_defaults for h in settings.values())
    hotend = settings["hotend"]
    assert hotend.sensor == THERMISTORS[EPCOS] and hotend.pullup_ohm == 4700
    assert hotend.control == DEFAULT_CONTROL["hotend"] and settings["bed"].control == DEFAULT_CONTROL["bed"]
    assert (hotend.max_temp_c, settings["bed"].max_temp_c, hotend.min_temp_c) == (275, 125, 5)
    assert hotend.plant == HOTEND and hotend.table().shape == (1024,)


def test_a_heaters_section_lists_its_heaters_with_defaults_filled(tmp_path):
    path = write(tmp_path, """\
      heaters:
        bed:
          sensor: {steinhart_hart: [7.2e-4, 2.2e-4, 1.0e-7]}
          control: {pid: {kp: 100, ki: 5, kd: 300}}
          max_power: 0.5
          plant: {heater_w: 200}
    """)
    settings = heater_settings(load_job(path))
    assert list(settings) == ["bed"] and not settings["bed"].board_defaults
    bed = settings["bed"]
    assert (bed.sensor.a, bed.sensor.b, bed.sensor.c) == (7.2e-4, 2.2e-4, 1.0e-7)
    assert bed.fixed_control().max_duty == 128 and bed.max_temp_c == 125
    assert bed.plant == Plant(300.0, 1.15, 200.0) and bed.protection == DEFAULT_PROTECTION["bed"]
