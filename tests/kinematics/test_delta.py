"""Delta kinematics: inverse and forward kinematics, derivatives, step reach, reachability, subdivision."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from codegen.job import load_job
from codegen.kinematics import make_kinematics
from codegen.kinematics.delta import MAX_ARM_RATIO, Delta
from codegen.toolpath.segments import flatten
from tests.helpers import ROOT, polyline, stepper

ROD, RADIUS, HEIGHT, SPM = 215.0, 105.2, 250.0, 80.0  # a Kossel mini
TOL = 0.002


def kossel(motors=("a", "b", "c", "e"), ranges=None, angles=(210.0, 330.0, 90.0)):
    steppers = {m: stepper(spm=SPM) for m in motors}
    for m, span in (ranges or {}).items():
        steppers[m].range = span
    machine = SimpleNamespace(kinematics="delta", motor_names=motors, steppers=steppers,
                              delta=SimpleNamespace(radius=RADIUS, diagonal_rod=ROD, height=HEIGHT,
                                                    tower_angles=angles))
    return make_kinematics(machine)


def reachable_points(kin, n, seed=0, radius=220.0):
    """Random reachable points, many of them near the edge of the reachable region (where rods are flat)."""
    rng = np.random.default_rng(seed)
    r = radius * np.sqrt(rng.uniform(0, 1, n))
    angle = rng.uniform(0, 2 * np.pi, n)
    points = np.column_stack([r * np.cos(angle), r * np.sin(angle), rng.uniform(-20, 250, n), rng.uniform(-5, 5, n)])
    return points[~kin.unreachable(points)]


def dense_deviation(kin, start, end, samples=200):
    """Largest distance of the effector from each straight piece when its carriages move linearly."""
    c0, c1 = kin.to_motor(start), kin.to_motor(end)
    t = np.linspace(0.0, 1.0, samples)
    carriages = (c0[:, None, :] + t[None, :, None] * (c1 - c0)[:, None, :]).reshape(-1, c0.shape[1])
    p = kin.to_axes(carriages, np.zeros((len(carriages), 4)))[:, :3].reshape(len(start), samples, 3)
    d, ab = p - start[:, None, :3], (end - start)[:, None, :3]
    along = np.einsum("nkj,nkj->nk", d, ab) / np.einsum("nkj,nkj->nk", ab, ab)
    return np.linalg.norm(d - along[..., None] * ab, axis=2).max(axis=1)


def fewest_uniform(kin, a, b):
    """The fewest equal pieces of the move a -> b that all stay within TOL (bisection)."""
    def fits(n):
        f = np.arange(n + 1)[:, None] / n
        points = a + f * (b - a)
        return dense_deviation(kin, points[:-1], points[1:], 100).max() <= TOL

    low, high = 0, 1
    while not fits(high):
        low, high = high, 2 * high
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (low, middle) if fits(middle) else (middle, high)
    return high


def test_make_kinematics_builds_delta_with_its_sockets():
    kin = kossel()
    assert isinstance(kin, Delta)
    assert [kin.socket(m) for m in kin.motors] == ["X", "Y", "Z", "E0"]


@pytest.mark.parametrize("angles", [(210.0, 330.0, 90.0), (200.0, 335.0, 95.0)])
def test_inverse_and_forward_kinematics_round_trip(angles):
    kin = kossel(angles=angles)
    points = reachable_points(kin, 40000)
    assert len(points) > 10000
    back = kin.to_axes(kin.to_motor(points), np.zeros_like(points))
    assert np.abs(back - points).max() < 1e-9  # e from the motor column too


def test_forward_kinematics_takes_undriven_axes_from_like():
    kin = kossel(motors=("a", "b", "c"))
    points = reachable_points(kin, 100)
    like = np.column_stack([np.zeros((len(points), 3)), np.full(len(points), 7.0)])
    back = kin.to_axes(kin.to_motor(points), like)
    assert np.abs(back[:, :3] - points[:, :3]).max() < 1e-9
    assert np.all(back[:, 3] == 7.0)


def test_carriage_formula_and_home():
    kin = kossel()
    p = np.array([[12.0, -30.0, 40.0, 0.0]])
    towers = [(RADIUS * math.cos(math.radians(a)), RADIUS * math.sin(math.radians(a))) for a in (210, 330, 90)]
    expected = [40.0 + math.sqrt(ROD ** 2 - (tx - 12.0) ** 2 - (ty + 30.0) ** 2) for tx, ty in towers]
    assert kin.to_motor(p)[0, :3] == pytest.approx(expected, abs=1e-12)
    home = kin.home()
    assert home.tolist() == [0.0, 0.0, HEIGHT, 0.0]
    top = HEIGHT + math.sqrt(ROD ** 2 - RADIUS ** 2)
    assert kin.to_motor(home[None, :])[0, :3] == pytest.approx([top] * 3, abs=1e-12)
    assert kin.to_steps(home[None, :])[0, :3].tolist() == [round(top * SPM)] * 3
    assert not kin.unreachable(home[None, :])[0]


def test_motor_factors_match_finite_differences():
    kin = kossel()
    points = reachable_points(kin, 2000, seed=1, radius=150.0)
    rng = np.random.default_rng(2)
    directions = rng.normal(size=points.shape)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    h = 1e-5
    numeric = np.abs(kin.to_motor(points + h * directions) - kin.to_motor(points - h * directions)) / (2 * h)
    assert kin.motor_factors(directions, points) == pytest.approx(numeric, rel=1e-6, abs=1e-6)


def test_step_reach_bounds_every_sampled_single_step():
    kin = kossel()
    reach = kin.step_reach()
    assert reach[3] == 0.0  # the extruder moves no xyz
    points = reachable_points(kin, 100000, seed=3)
    carriages = kin.to_motor(points)
    worst = np.zeros(3)
    for m in range(3):
        for sign in (1.0, -1.0):
            moved = carriages.copy()
            moved[:, m] += sign / SPM
            shift = np.linalg.norm(kin.to_axes(moved, points)[:, :3] - points[:, :3], axis=1)
            worst[m] = max(worst[m], np.nanmax(shift))
    assert np.all(worst <= reach[:3])
    assert np.all(worst >= 0.95 * reach[:3])  # and it is tight: about 1.33 carriage steps


def test_unreachable_points():
    kin = kossel(ranges={"a": (10.0, 1000.0)})
    rise = math.sqrt(ROD ** 2 - RADIUS ** 2)  # every carriage's height above the nozzle at the centre
    edge = ROD * MAX_ARM_RATIO / math.hypot(1.0, MAX_ARM_RATIO) - RADIUS  # opposite tower c, rod c at 12:1
    outside = np.array([
        [0.0, -(ROD - RADIUS) - 1.0, 5.0, 0.0],  # beyond rod c
        [0.0, -edge - 0.5, 5.0, 0.0],  # rod c too flat
        [0.0, 0.0, HEIGHT + 0.5, 0.0],  # every carriage above the top of its tower
        [60.0, 0.0, HEIGHT, 0.0],  # the same height off-centre: carriage c higher still
        [0.0, 0.0, 10.0 - rise - 0.5, 0.0],  # carriage a below its range
    ])
    assert kin.unreachable(outside).tolist() == [True] * len(outside)
    t = np.linspace(0.0, 2.0 * math.pi, 50)
    circle = np.column_stack([60 * np.cos(t), 60 * np.sin(t), np.full(50, 5.0), np.zeros(50)])
    inside = np.concatenate([circle, [[0.0, -edge + 0.5, 5.0, 0.0], [0.0, 0.0, 10.0 - rise + 0.5, 0.0],
                                      [0.0, 0.0, HEIGHT, 0.0]]])
    assert not np.any(kin.unreachable(inside))



@pytest.mark.parametrize("ranges, low, high", [(None, 0.3, 0.3), (None, 0.3, 240.0), ({"b": (180.0, 400.0)}, 0.0, 60.0),
                                               ({"c": (0.0, 420.0)}, 0.0, 200.0)])
def test_reach_is_the_largest_disc_reachable_at_every_height_between(ranges, low, high):
    kin = kossel(ranges=ranges)
    r = kin.reach(low, high)
    t = np.linspace(0.0, 2.0 * math.pi, 7201)

    def unreachable(radius, z):
        return np.any(kin.unreachable(np.column_stack([radius * np.cos(t), radius * np.sin(t), z + 0 * t, 0 * t])))

    assert r > 0.0 and not unreachable(0.9999 * r, low) and not unreachable(0.9999 * r, high)
    assert unreachable(1.0002 * r, low) or unreachable(1.0002 * r, high)
    assert kin.highest(r) >= high - 1e-9


def test_highest_is_where_the_carriages_reach_their_tops():
    kin = kossel()
    assert kin.highest(kin.reach(0.3, 240.0)) == pytest.approx(240.0) and kin.highest(0.0) == pytest.approx(HEIGHT)
    assert kin.reach(0.0, HEIGHT + 1.0) < 0.0  # above the home height not even the centre

MOVES = {
    "through the centre": ((-80.0, 0.0, 5.0), (80.0, 0.0, 5.0)),
    "diagonal, climbing": ((-60.0, -60.0, 1.0), (60.0, 60.0, 100.0)),
    "near the edge": ((60.0, -100.0, 5.0), (60.0, 80.0, 5.0)),
    "short": ((-10.0, -10.0, 5.0), (10.0, 10.0, 5.0)),
}


@pytest.mark.parametrize("move", MOVES.values(), ids=MOVES.keys())
def test_subdivide_keeps_every_piece_within_tolerance_with_few_pieces(move):
    kin = kossel()
    a, b = np.array(move[0] + (0.0,)), np.array(move[1] + (3.0,))
    assert not np.any(kin.unreachable(np.array([a, b])))
    segments = flatten(polyline([move[0], move[1]], feed=50.0), TOL)
    segments.end[0, 3] = 3.0  # extruding along the move
    pieces = kin.subdivide(segments, TOL)
    assert dense_deviation(kin, pieces.start, pieces.end).max() <= TOL
    assert len(pieces) <= 2 * fewest_uniform(kin, a, b)
    # contiguous, exact ends, on the line, every field carried over
    assert np.array_equal(pieces.start[0], a) and np.array_equal(pieces.end[-1], b)
    assert np.array_equal(pieces.start[1:], pieces.end[:-1])
    f = (pieces.end - a) @ (b - a) / np.dot(b - a, b - a)
    assert np.allclose(pieces.end, a + f[:, None] * (b - a), atol=1e-9)
    assert np.all(pieces.feed == 50.0) and np.all(pieces.tool) and np.all(pieces.item == segments.item[0])


def test_subdivide_cuts_moves_near_the_edge_finer():
    kin = kossel()
    counts = {}
    for name in ("through the centre", "near the edge"):
        a, b = MOVES[name]
        pieces = kin.subdivide(flatten(polyline([a, b], feed=50.0), TOL), TOL)
        length = math.dist(a, b)
        counts[name] = (len(pieces), length / len(pieces))
    assert counts["near the edge"][1] < counts["through the centre"][1]


def test_subdivide_leaves_vertical_moves_dwells_and_extrusion_alone():
    kin = kossel()
    segments = flatten(polyline([(0, 0, 5), (0, 0, 50), (20, 0, 50)], feed=20.0), TOL)
    segments.end[0, 3] = 2.0
    pieces = kin.subdivide(segments, TOL)
    vertical = pieces.item == segments.item[0]
    assert vertical.sum() == 1 and np.array_equal(pieces.end[vertical][0], segments.end[0])
    later = pieces.item == segments.item[1]
    assert later.sum() > 1
    assert np.isnan(pieces.jerk[later][1:]).all()  # only where a move starts


def test_subdivide_refuses_a_move_out_of_reach():
    kin = kossel()
    with pytest.raises(ValueError, match="reachable"):
        kin.subdivide(flatten(polyline([(0, 0, 5), (200, 0, 5)], feed=20.0), TOL), TOL)


def test_seed_machine_reaches_its_targets_from_10828_steps():
    job = load_job(ROOT / "examples" / "delta-seed.yaml")
    kin = make_kinematics(job.machine)
    assert kin.to_steps(kin.home()[None, :])[0].tolist() == [10828] * 3
    targets = np.array([[100.0, 20.0, 50.0, 0.0], [-60.0, 70.0, 30.0, 0.0]])
    assert not np.any(kin.unreachable(targets))
    dx, dy, rise = kin._arms(targets[:, :2])
    assert np.degrees(np.arctan2(rise, np.hypot(dx, dy))).min() > 45.0  # every rod well above horizontal


@settings(max_examples=30, deadline=None)
@given(point=st.tuples(*(st.floats(-60, 60),) * 2, st.floats(0, 100)),
       velocity=st.tuples(*(st.floats(-200, 200),) * 3), accel=st.tuples(*(st.floats(-5000, 5000),) * 3))
def test_carriage_motion_is_the_derivative_of_the_carriages(point, velocity, accel):
    """Along a quadratic effector path, the carriages' velocity and acceleration are those of their positions
    (central differences of to_motor)."""
    kin = kossel()
    p, v, a = (np.array([[*xyz, 0.0]]) for xyz in (point, velocity, accel))
    h = 1e-4
    at = [kin.to_motor(p + v * t + 0.5 * a * t * t) for t in (-h, 0.0, h)]
    c, speed, bend = kin.carriage_motion(p, v, a)
    assert np.allclose(c, at[1], rtol=0, atol=1e-9)
    assert np.allclose(speed, (at[2] - at[0]) / (2 * h), rtol=0, atol=1e-4)
    assert np.allclose(bend, (at[2] - 2 * at[1] + at[0]) / (h * h), rtol=0, atol=0.5)
