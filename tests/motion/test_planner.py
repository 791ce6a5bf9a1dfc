"""Planner invariants against hand-computed cases."""

import math

import numpy as np
import pytest

from codegen.kinematics import make_kinematics
from codegen.motion.planner import CATCH_UP_SHARE, PlannerLimits, catch_up_time, profile
from codegen.motion.stepgen import segment_steps
from codegen.toolpath.items import Arc, Line, Toolpath
from codegen.toolpath.segments import flatten
from tests.helpers import SRC, machine, planned, point, polyline

KEEP = 0.98  # the planner's headroom below every limit


def test_long_line_is_a_trapezoid_with_hand_computed_duration():
    _, _, _, p = planned(polyline([(0, 0), (100, 0)], feed=50), machine(x={"amax": 1000}))
    a = 1000 * KEEP
    assert p.v_peak[0] == pytest.approx(50)
    assert p.accel[0] == pytest.approx(a)
    assert p.s_acc[0] == pytest.approx(50 ** 2 / (2 * a))
    assert p.total == pytest.approx(100 / 50 + 50 / a)


def test_short_move_is_a_triangle():
    _, _, _, p = planned(polyline([(0, 0), (1, 0)], feed=100), machine(x={"amax": 1000}))
    a = 1000 * KEEP
    assert p.s_cruise[0] == pytest.approx(0, abs=1e-12)
    assert p.v_peak[0] == pytest.approx(math.sqrt(a * 1.0))
    assert p.total == pytest.approx(2 * math.sqrt(1.0 / a))


def test_right_angle_corner_uses_grbl_junction_deviation():
    _, _, _, p = planned(polyline([(0, 0), (50, 0), (50, 50)], feed=100), jd=0.01)
    a_normal = 3000 * KEEP / math.sqrt(0.5)  # the junction vector (-1, 1)/sqrt(2) loads each motor by 0.707
    sin_half = math.sin(math.radians(45))
    assert p.v_exit[0] == pytest.approx(math.sqrt(a_normal * 0.01 * sin_half / (1 - sin_half)))
    assert p.v_entry[1] == p.v_exit[0]


def test_collinear_segments_do_not_slow_down_and_reversal_stops():
    _, _, _, p = planned(polyline([(0, 0), (50, 0), (100, 0)], feed=40))
    assert p.v_exit[0] == pytest.approx(40)
    _, _, _, back = planned(polyline([(0, 0), (50, 0), (10, 0)], feed=40))
    assert back.v_exit[0] == 0.0


def test_motor_velocity_limits_project_onto_corexy_belts():
    mach = machine("corexy", ("a", "b"), a={"vmax": 100}, b={"vmax": 100})
    _, _, _, p = planned(polyline([(0, 0), (300, 0)], feed=1e9), mach)
    assert p.v_peak[0] == pytest.approx(100 * KEEP)  # an x move turns both belts at full speed
    _, _, _, diag = planned(polyline([(0, 0), (200, 200)], feed=1e9), mach)
    assert diag.v_peak[0] == pytest.approx(100 * KEEP / math.sqrt(2))  # a diagonal turns belt a sqrt(2) as fast


def test_slave_speed_allows_for_bresenham_quantisation():
    # z is the slave (9 steps per 10 of x); z's limit binds. 8 consecutive z steps may span only 7 master events.
    mach = machine("cartesian", ("x", "z"), x={"spm": 100}, z={"spm": 100, "vmax": 10})
    tp = Toolpath(point(0, 0), [Line(point(0, 0, 0), point(10, 0, 9), 1e9, True, SRC)])
    _, _, steps, p = planned(tp, mach)
    assert list(steps[0]) == [1000, 900]
    u_z = 9 / math.hypot(10, 9)
    worst = 7 / math.floor(7 * 1000 / 900)  # slave rate over 8 steps / nominal rate
    assert p.v_peak[0] * u_z * worst <= 10 * KEEP * (1 + 1e-9)
    assert p.v_peak[0] * u_z > 10 * KEEP * 0.8


def test_circle_speed_keeps_centripetal_acceleration_within_motor_limits():
    r = 5.0
    arc = Arc(point(r, 0), point(r, 0), (0.0, 0.0), r, 0.0, 2 * math.pi, 1e9, True, SRC)
    _, _, _, p = planned(Toolpath(point(r, 0), [arc]))
    middle = p.v_peak[len(p.v_peak) // 2]
    a = 3000 * KEEP
    assert middle ** 2 / r <= 0.8 * a * math.sqrt(2) * 1.001
    assert middle ** 2 / r >= 0.8 * a * 0.99


def test_unequal_chords_on_a_circle_keep_its_radius():
    """Chords of alternating lengths (0.2 and 1 mm) on a circle: each vertex's curvature is the circle's, so the
    long chords go as fast as the centripetal limit allows, no slower (as if every chord were the short one)."""
    r, a = 10.0, 3000 * KEEP
    angles = np.cumsum(np.tile([2 * math.asin(0.1 / r), 2 * math.asin(0.5 / r)], 30))
    points = [(r * math.cos(t), r * math.sin(t)) for t in np.concatenate([[0.0], angles])]
    _, _, _, p = planned(polyline(points, feed=1e9))
    middle = p.v_peak[20:40]
    assert np.all(middle ** 2 / r <= 0.8 * a * math.sqrt(2) * 1.001)
    assert np.all(middle ** 2 / r >= 0.8 * a * 0.99)


def test_a_blip_of_a_chord_does_not_slow_the_long_move_beside_it():
    """`G1 X10 / G1 X10.001 / G1 X20 Y-1` at F3600: the 0.1 rad turn after a 1 um chord is a corner (junction
    deviation), not a curve of radius 10 um; Klipper goes through at 60 mm/s too."""
    _, _, _, p = planned(polyline([(0, 0), (10, 0), (10.001, 0), (20, -1)], feed=60))
    assert p.v_peak[2] == pytest.approx(60)
    assert p.v_exit[1] == pytest.approx(60)


def test_passes_respect_acceleration_between_every_junction():
    rng = np.random.default_rng(7)
    pts = np.cumsum(rng.uniform(-3, 3, size=(300, 2)), axis=0)
    _, _, _, p = planned(polyline(pts, feed=150))
    gain = 2 * p.accel * p.length
    assert np.all(p.v_exit ** 2 <= p.v_entry ** 2 + gain + 1e-6)
    assert np.all(p.v_entry ** 2 <= p.v_exit ** 2 + gain + 1e-6)
    assert np.all(p.v_peak <= 150 + 1e-9)
    assert p.v_entry[0] == 0 and p.v_exit[-1] == 0
    assert np.all(p.v_entry[1:] == p.v_exit[:-1])
    assert np.all(p.s_acc + p.s_cruise <= p.length + 1e-9)


def test_time_at_matches_segment_ends():
    _, _, _, p = planned(polyline([(0, 0), (30, 0), (30, 30)], feed=80))
    seg = np.array([0, 0, 1, 1])
    s = np.array([0.0, p.length[0], 0.0, p.length[1]])
    t = p.time_at(seg, s)
    assert t[0] == 0.0
    assert t[1] == pytest.approx(p.t_start[1])
    assert t[2] == pytest.approx(p.t_start[1])
    assert t[3] == pytest.approx(p.total)


def _with_program_limits(toolpath, mach=None, **items):
    from codegen.toolpath.items import Limits
    toolpath.items.insert(0, Limits(SRC, **items))
    return planned(toolpath, mach)


def test_program_limits_cap_the_machine_ones():
    _, _, _, p = _with_program_limits(polyline([(0, 0), (100, 0)], feed=1e9), max_velocity={"x": 50.0},
                                      max_accel={"x": 500.0})
    assert p.v_peak[0] == pytest.approx(50.0)
    assert p.accel[0] == pytest.approx(500.0)
    _, _, _, fast = _with_program_limits(polyline([(0, 0), (100, 0)], feed=1e9), max_velocity={"x": 1000.0})
    assert fast.v_peak[0] == pytest.approx(200 * KEEP)  # never above the machine's own limit


def test_classic_jerk_sets_corner_speed_when_the_program_asks_for_it():
    _, _, _, p = _with_program_limits(polyline([(0, 0), (50, 0), (50, 50)], feed=100), jerk={"x": 8.0, "y": 8.0})
    assert p.v_exit[0] == pytest.approx(8.0)  # x drops from v to 0 and y rises from 0 to v: 8 mm/s each


def test_move_acceleration_cap_from_the_program():
    tp = polyline([(0, 0), (100, 0)], feed=100)
    tp.items[0] = Line(tp.items[0].start, tp.items[0].end, 100, True, SRC, accel=400.0)
    _, _, _, p = planned(tp)
    assert p.accel[0] == pytest.approx(400.0)


def test_catch_up_time_leaves_a_block_the_time_to_make_up_its_load():
    """A block load longer than one event's gap at the compressor's catch-up pace (98.5 % of the rate) delays the
    first event by the load; the other N - 1 events come at that pace at the most: N - 1 gaps + the load."""
    steps = np.array([[36, 20], [36, 0], [0, 0]])
    master = 36 / (CATCH_UP_SHARE * 6000)  # the slave, at 12 of 12.6 events per 7 steps, needs less
    assert catch_up_time(steps, np.array([6000.0, 6000.0]), PlannerLimits(0.01, block_load=351e-6)) \
        == pytest.approx([master * 35 / 36 + 351e-6, master * 35 / 36 + 351e-6, 0.0], rel=1e-12)
    # a load no longer than the gap delays nothing
    assert catch_up_time(steps, np.array([6000.0, 6000.0]), PlannerLimits(0.01, block_load=160e-6)).tolist() \
        == [0.0, 0.0, 0.0]


def test_short_block_at_full_rate_slows_for_its_block_load():
    """The 8051's case (tests/data/jobs/found/moves-behind-the-block-loads.yaml): 36 steps at 6000 steps/s with
    a 351 us block load; at the motor's 98 % the player fell 0.1 ms behind the plan at every block."""
    kin = make_kinematics(machine(x={"spm": 100, "vmax": 60}))
    segments = flatten(polyline([(0, 0), (0.36, 0)], feed=1000), 0.002)
    steps = segment_steps(segments, kin)
    assert steps.tolist() == [[36, 0]]
    free = profile(segments, kin, steps, PlannerLimits(0.01))
    loaded = profile(segments, kin, steps, PlannerLimits(0.01, block_load=351e-6))
    assert math.sqrt(free.w_nominal[0]) == pytest.approx(60 * KEEP)
    assert math.sqrt(loaded.w_nominal[0]) == pytest.approx(0.36 / (35 / (CATCH_UP_SHARE * 6000) + 351e-6))
