"""Pressure advance in the simulator: the extruder's simulated position at every pulse against Klipper's formula.

The tables carry the advanced extruder as the host fitted it (codegen/motion/advance.py); this check does not
read that fit. It takes the plan before shaping (the segments with their K), evaluates the formula exactly at
every simulated extruder pulse's planned time (its twin pulse's event, on the plan's clock: the shaped clock less
its delay; the timing check holds the pulse to that time, late block loads and all) and measures how far it lies
from the extruder's position there (the nearer of the positions before and after the pulse,
`AdvanceReference.worst`). It holds within a step: a step made where the formula crosses the half step is 0 off;
the blocks' chords (half a step from the motion at most) and the Bresenham coupling of a slave (about half a step
more) move a pulse by less than a step and a half. A kept build's whole plan gives the formula (`host.planned`),
nominal (K 0 throughout so far) up to where the host first smoothed each era's extruder (`Totals.smoothed_from`,
codegen/motion/advance.py); verify in bounded memory has each window's, its chapter's windows'
(`Chapter.advance`), each for the pulses of its own stretch. A held run's clock is dilated, so it is not checked
there.
"""

from __future__ import annotations

import numpy as np

from codegen.motion.advance import AdvanceReference, advance_reference
from codegen.motion.shaped_motion import planned_motion
from codegen.pipeline.host import HostBuild
from codegen.tables.checks import ADVANCE_LIMIT_STEPS
from codegen.toolpath.segments import Segments


class AdvanceCheck:
    """`add` the simulated pulses a chapter at a time (seconds on the twin's clock), then `problems`."""

    def __init__(self, references: list[AdvanceReference], motor: int, steps_per_mm: float, start_steps: int):
        """`references`: the whole program's formula ([]: each chapter brings its windows')."""
        self.references, self.motor, self.steps_per_mm = references, motor, steps_per_mm
        self.position = int(start_steps)  # the extruder's absolute step so far
        self.worst = (0.0, 0.0, 0)  # steps, when (s), G-code line

    def add(self, time: np.ndarray, motor: np.ndarray, direction: np.ndarray,
            references: list[AdvanceReference] | None = None, planned: np.ndarray | None = None) -> None:
        """`references`: the chapter's windows' formulas (None: the whole program's); `planned` (s): the planned
        time of each of the extruder's pulses (its twin pulse's event), where the formula is evaluated (None: at
        the simulated times). A pulse the player makes late, as a slow block load allows (the timing check
        holds it to its own rule), is held at the time it was meant for."""
        mine = motor == self.motor
        if not np.any(mine):
            return
        time, direction = (time[mine] if planned is None else planned), direction[mine]
        after = self.position + np.cumsum(direction)
        self.position = int(after[-1])
        for reference in references or self.references:
            inside = (time >= reference.begin) & (time <= reference.end)
            worst = reference.worst(time[inside], direction[inside], after[inside], self.steps_per_mm)
            if worst[0] > self.worst[0]:
                self.worst = worst

    def problems(self) -> list[str]:
        steps, time, line = self.worst
        if steps <= ADVANCE_LIMIT_STEPS:
            return []
        return [f"motor e (the extruder) is {steps:.2f} steps from the pressure advance formula at {time:.4f} s"
                + (f" on G-code line {line}" if line else "") + f" (limit {ADVANCE_LIMIT_STEPS:g} step)"]


def advance_check(host: HostBuild, segments: Segments | None = None) -> AdvanceCheck | None:
    """The check of a build whose extruder is advanced (None otherwise): against a kept build's whole plan, or the
    chapters' (the bounded verify's); `segments`: the kept plan's segments with other K (the build's own: None).
    Each era of the input shapers (between M593s) has its own shaped clock, so its own reference for its stretch."""
    eras = host.shapings or (host.settings.stages.shaping,)
    if all(shaping is None or shaping.advance is None for shaping in eras):
        return None
    references = []
    if host.planned is not None:
        planned_segments, plan = host.planned
        segments = planned_segments if segments is None else segments
        motion = planned_motion(segments, plan)
        era_of = segments.shaping[motion.origin]
        for era, shaping in enumerate(eras):
            pieces = np.flatnonzero(era_of == era)
            if shaping is None or shaping.advance is None or not len(pieces):
                continue
            first, last = int(pieces[0]), int(pieces[-1]) + 1  # an era's pieces follow one another
            span = (-np.inf if first == 0 else motion.breaks[first], np.inf if last == len(motion) else
                    motion.breaks[last])
            # Nominal until the window whose extruder the host smoothed first, smoothed from there on.
            smoothed_from = min(max(host.totals.smoothed_from.get(era, np.inf), span[0]), span[1])
            parts = ((span[0], np.nextafter(smoothed_from, -np.inf), False), (smoothed_from, span[1], True))
            for begin, end, smooth in parts:
                if begin < end:
                    references.append(advance_reference(
                        motion.breaks[first:last + 1], motion.position[first:last, 3], motion.velocity[first:last, 3],
                        motion.accel[first:last, 3], motion.origin[first:last], segments, shaping.advance.half,
                        shaping.shift, (begin, end), smooth))
    e = host.kin.motors.index("e")
    return AdvanceCheck(references, e, float(host.kin.limits.steps_per_mm[e]), int(host.start_steps[e]))
