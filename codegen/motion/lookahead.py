"""Lookahead over a stream of segments: the whole program's plan, one window at a time, in bounded memory.

The planner's backward pass runs from a stop at the end of what it holds. A junction is *settled* when the
segments after it, all held, gain at least its own limit at full acceleration: a stop at the end can then not
reach back to it, and neither can anything that comes later, so its speed (and every speed before it) is the
one a plan of the whole program gives (Grbl's planner and Klipper's lookahead hold no more than that either).
Each window ends at the last settled corner (a junction that is not part of a curve), so that the stages after
the planner, which look at a block's neighbours along a curve, never need a neighbour in another window. A long
stretch without a corner (one long straight move: the front end cuts it into blocks of at most MAX_MODULUS steps,
codegen/motion/staircase.py split_long) ends, once it holds more than WINDOW_EVENTS master steps, at its last
settled straight junction (collinear pieces: curve timing there is the chords' own, so no time changes), or with
none past twice that, at a settled junction of a curve: a window's steps, and the memory of every stage after it,
stay bounded whatever one move's length (issue 28). A segment's
own limits wait for the junction after it (its curvature there), and the window's last segment stays held as
the next window's context: every junction is planned from both of its segments, as in the whole program.

A window also ends where the input shapers' era changes (an M593, codegen/toolpath/segments.py): the plan rests
there, so that junction is final as soon as the next era's first segment is held, and every window is shaped
alike (codegen/pipeline/windows.py).

The speeds are the whole program's to rounding: the passes sum their gains from the window's start rather than
the program's, so junction speeds agree to a few units in the last place, and times to a few nanoseconds.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Iterator

import numpy as np

from codegen.kinematics.base import Kinematics
from codegen.motion.planner import Plan, PlannerLimits, Profile, finish, passes, profile, settled
from codegen.toolpath.segments import Segments, concat

MAX_HELD = 1 << 16  # segments held without a settled corner: then a window ends at a settled junction of a curve
WINDOW_EVENTS = 1 << 18  # master steps held without a settled corner: then a window ends at a straight junction
STRAIGHT_COS = 1.0 - 1e-12  # cosine of the turn at a junction between collinear pieces of one straight move


@dataclass
class Window:
    first: int  # the program's index of the window's first segment
    segments: Segments
    steps: np.ndarray  # (n, M) signed motor steps of every segment
    plan: Plan
    curve_cut: bool = False  # the window ends inside a curve (more than MAX_HELD segments without a corner)


def merge(a: Window, b: Window) -> Window:
    """Two consecutive windows as one."""
    return Window(a.first, concat(a.segments, b.segments), np.concatenate([a.steps, b.steps]),
                  Plan.join([a.plan, b.plan]), b.curve_cut)


class Lookahead:
    """`push` segments as they come (with their steps), `close` at the program's end; each gives the windows
    whose plan is final, in order, each planned when it is asked for (after the one before has been played, and
    maybe slowed: `resume`)."""

    def __init__(self, kin: Kinematics, limits: PlannerLimits):
        self.kin, self.limits = kin, limits
        self.held: Segments | None = None  # the last committed segment (context) first, when there is one
        self.held_steps = np.zeros((0, len(kin.motors)), dtype=np.int64)
        self.context = 0  # 1 once a window has been committed: held[0] is its last segment
        self.first = 0  # the program's index of held[self.context]
        self.w_first = 0.0  # v^2 at the junction before held[self.context]: final
        self.t0 = 0.0  # s: when that junction is passed
        self.straight_cap: tuple[np.ndarray, float] | None = None  # slow_straight_on's line and feed, while it goes on

    def push(self, segments: Segments, steps: np.ndarray) -> Iterator[Window]:
        if len(segments) == 0:
            return iter(())
        segments = self._capped(segments)
        self.held = segments if self.held is None else concat(self.held, segments)
        self.held_steps = np.concatenate([self.held_steps, steps])
        return self._commit_all(final=False)

    def close(self) -> Iterator[Window]:
        return self._commit_all(final=True)

    def _commit_all(self, final: bool) -> Iterator[Window]:
        """The windows final now: one, or after a window that ends at an era change, the ones that follow it."""
        while (window := self._commit(final)) is not None:
            yield window
            if not self._era_end(window):
                return

    def _era_end(self, window: Window) -> bool:
        """Whether the window ends where the shapers' era changes (the next segment held begins another)."""
        return self.held is not None and len(self.held) > 1 and self.held.shaping[1] != window.segments.shaping[-1]

    def _era_cut(self) -> int | None:
        """The first segment held (after the context) whose shapers' era differs from the one before it."""
        era = self.held.shaping[self.context:]
        change = np.flatnonzero(era[1:] != era[:-1])
        return int(change[0]) + 1 if len(change) else None

    def resume(self, w: float, t0: float) -> None:
        """The window before was planned again, slower: the next one starts at v^2 = `w` at most, at `t0`."""
        self.w_first, self.t0 = min(self.w_first, w), t0

    def slow_straight_on(self, feed: float) -> None:
        """The window before was played slowed, its last segment at `feed` (mm/s; a motor over its limit there):
        the pieces that go on in a straight line from it, held or still to come, start no faster, so that a long
        move at a motor's limit is not slowed, and played again with the window before, in every window (issue 28)."""
        held = self.held
        if held is None or not self.context:
            return
        self.straight_cap = (_directions(held)[0], feed)
        self.held = concat(held.take(np.arange(1)), self._capped(held.take(np.arange(1, len(held)))))

    def _capped(self, segments: Segments) -> Segments:
        """`segments` with the straight cap (slow_straight_on) on those that go on in its line; the cap ends at the
        first that does not."""
        if self.straight_cap is None or not len(segments):
            return segments
        direction, feed = self.straight_cap
        collinear = _directions(segments) @ direction >= STRAIGHT_COS
        run = len(collinear) if collinear.all() else int(np.argmin(collinear))
        if run < len(collinear):
            self.straight_cap = None
        return replace(segments, feed=np.concatenate([np.minimum(segments.feed[:run], feed), segments.feed[run:]]))

    def next_segment(self) -> Segments | None:
        """The first segment after the windows so far (its geometry is final, its plan is not)."""
        return self.held.take(np.arange(1, 2)) if self.held is not None and len(self.held) > 1 else None

    def _commit(self, final: bool) -> Window | None:
        held = 0 if self.held is None else len(self.held) - self.context
        if held == 0:
            return None
        prof = profile(self.held, self.kin, self.held_steps, self.limits).part(self.context, len(self.held))
        curve_cut, era_cut = False, self._era_cut()
        if era_cut is not None:  # the plan rests there: final whatever follows
            end = era_cut
        elif final:
            end = held
        else:
            # The last segment's own limits wait for the junction after it (its curvature there).
            prof = prof.part(0, held - 1)
            plan = finish(prof, passes(prof, self.w_first, 0.0), self.t0)
            ok = settled(prof)
            ok[0] = ok[-1] = False
            ends = np.flatnonzero(ok & plan.corner)
            events = self._held_events() if len(ends) == 0 else 0
            if events > WINDOW_EVENTS:
                ends = np.flatnonzero(ok & _straight(prof))
            # A curve's straight junctions (inside a long chord) settle a stopping distance later: wait for them.
            if len(ends) == 0 and (held > MAX_HELD or events > 2 * WINDOW_EVENTS):
                ends, curve_cut = np.flatnonzero(ok), True
            if len(ends) == 0:
                return None
            end = int(ends[-1])
        w = passes(prof, self.w_first, 0.0)
        plan = finish(prof.part(0, end), w[:end + 1], self.t0)
        lo = self.context
        window = Window(self.first, self.held.take(np.arange(lo, lo + end)), self.held_steps[lo:lo + end], plan,
                        curve_cut)
        self.first += end
        self.w_first = float(w[end])
        self.t0 = plan.total if len(plan.duration) else self.t0
        keep = np.arange(lo + end - 1, len(self.held))
        self.held = self.held.take(keep).compact()
        self.held_steps = self.held_steps[keep]
        self.context = 1
        return window

    def _held_events(self) -> int:
        """The master steps of the segments held (the context's included)."""
        return int(np.abs(self.held_steps).max(axis=1, initial=0).sum())


def _directions(segments: Segments) -> np.ndarray:
    """(n, 3) every piece's unit direction in xyz (zeros for a piece that does not move)."""
    delta = segments.end[:, :3] - segments.start[:, :3]
    return delta / np.maximum(np.linalg.norm(delta, axis=1, keepdims=True), 1e-300)


def _straight(prof: Profile) -> np.ndarray:
    """(n + 1,) the junctions between two collinear moving pieces of a stretch (False at its ends)."""
    straight = np.zeros(len(prof) + 1, dtype=bool)
    cos_turn = np.sum(prof.direction[:-1] * prof.direction[1:], axis=1)
    straight[1:-1] = prof.moving[:-1] & prof.moving[1:] & (cos_turn >= STRAIGHT_COS)
    return straight
