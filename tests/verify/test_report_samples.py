"""What verify --report draws, gathered a chapter at a time (codegen/verify/report_samples.py RunSamples): its size
does not grow with the run (a run and the same run twice as long give samples of the same size), and what it keeps
of the timing is exact: every pulse's error counted once."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from codegen.sim.avr_edges import Steps
from codegen.verify.report_samples import MAX_DISTINCT, MAX_POINTS, RunSamples

F_CPU, TICK_HZ, CHAPTER = 16_000_000, 2_000_000, 1 << 15


def gathered(pulses: int) -> RunSamples:
    """A two-motor run of `pulses` pulses 1 ms apart (motors taking turns, each turning every 1000 of its steps),
    each up to 39 cycles late against the twin, handed over a chapter at a time."""
    host = SimpleNamespace(kin=SimpleNamespace(motors=("x", "y")), laser=None,
                           target=SimpleNamespace(tick_hz=TICK_HZ),
                           totals=SimpleNamespace(duration_s=pulses / 1000, segments=0))
    samples = RunSamples(host, F_CPU)
    late = np.random.default_rng(7).integers(0, 40, pulses)
    for lo in range(0, pulses, CHAPTER):
        k = np.arange(lo, min(lo + CHAPTER, pulses))
        motor = k % 2
        sim = Steps((k + 1) * 16_000 + late[k], motor, np.where((k // 2000) % 2, -1, 1))
        twin = SimpleNamespace(tick=(k + 1) * 16_000 // (F_CPU // TICK_HZ), motor=motor)
        chapter = SimpleNamespace(plan=None, segments=(), last=lo + CHAPTER >= pulses, pulses=twin)
        samples.add(chapter, sim, sim.cycle, 0)
    return samples


def sizes(samples: RunSamples) -> list[tuple[int, ...]]:
    cycle, steps = samples.simulated()
    times, positions = samples.positions()
    return [cycle.shape, steps.shape, times.shape, positions.shape] + [
        values.shape for values, _ in samples.timing_us().values()]


def test_the_samples_of_a_run_twice_as_long_are_no_bigger():
    once, twice = gathered(1 << 18), gathered(1 << 19)
    assert sizes(once) == sizes(twice)
    assert twice.stride == 2 * once.stride and twice.grid_s == 2 * once.grid_s
    cycle, steps = twice.simulated()
    assert len(cycle) <= MAX_POINTS + 1 and twice.positions()[1].shape[1] <= 2 * MAX_POINTS + 1
    assert cycle[-1] == twice.last_cycle and np.array_equal(steps[-1], twice.net)


def test_every_pulse_is_in_the_timing_histogram_at_its_error():
    samples = gathered(1 << 18)
    late = np.random.default_rng(7).integers(0, 40, 1 << 18)
    for m, (values, counts) in enumerate(samples.timing_us().values()):
        expected = np.bincount(late[m::2], minlength=40)
        assert np.array_equal(values, np.arange(40) / F_CPU * 1e6) and np.array_equal(counts, expected)
    assert len(values) <= MAX_DISTINCT and samples.quantum == 1


def test_a_motor_whose_pulses_do_not_pair_has_no_histogram():
    samples = gathered(3 * CHAPTER)
    samples.extra(Steps(np.array([10**12]), np.array([1]), np.array([1])))
    assert list(samples.timing_us()) == ["x"] and samples.count == 3 * CHAPTER + 1
