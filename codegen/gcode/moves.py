"""The interpreter's positions and moves: targets in machine mm, G0/G1 lines, G2/G3 arcs, G28 and G92.

Machine position = program position + offset (work system, G92, tool length: codegen/gcode/grbl.py). Moves are
recorded as indices into one list of points (`flat`, 4 numbers a point, from point `base` of the program on),
the C's runs of lines as rows of its arrays (codegen/gcode/fast.py); `take` turns them into Lines/Arc/Home items.
"""

from __future__ import annotations

import math

import numpy as np

import codegen.gcode.arcs as arcs
import codegen.toolpath.limits as limits
from codegen.gcode.codes import AXIS_LETTERS, PLANE_NAMES
from codegen.gcode.fast import RUN
from codegen.toolpath.items import Arc, Home, Lines

LINE, ARC, HOME = 0, 1, 2
AXIS_INDEX = {letter: i for i, letter in enumerate(AXIS_LETTERS)}
OFFSET_LETTERS = {(0, 1): "IJ", (2, 0): "KI", (1, 2): "JK"}  # the I/J/K of the plane's (u, v) axes


class Moves:
    """Mixed into the Interpreter: uses its state (pos, off, unit, modes, feeds, tool) and diagnostics."""

    def take(self) -> list:
        """The items made since the last `take`: every point a row of one read-only array, each Arc/Home holding
        views of its rows, and the lines one after another (Python's and the C's runs) one Lines item. Only
        the current point stays (the next move starts there)."""
        array = np.array(self.flat, dtype=float).reshape(-1, 4)
        array.flags.writeable = False
        rows, base = list(array), self.base  # point i of the program is rows[i - base]
        items, lines = [], []
        for it in self.items:
            if type(it) is tuple and (it[0] == LINE or it[0] == RUN):
                lines.append(it)
                continue
            if lines:
                items.append(self._lines(lines, rows, base))
                lines = []
            if type(it) is not tuple:
                items.append(it)
            elif it[0] == ARC:
                _, a, b, c, plane, feed, tool, src, label, accel, power, dynamic = it
                items.append(Arc(rows[a - base], rows[b - base], c.center, c.radius, c.start_angle, c.sweep, feed,
                                 tool, src, plane, label, accel, power, dynamic, c.radius_change))
            else:
                _, axes, a, src = it
                items.append(Home(axes, rows[a - base], src))
        if lines:
            items.append(self._lines(lines, rows, base))
        if self.native is not None:
            self.native.clear()
        self.items = []
        self.flat = self.flat[4 * (self.cur - base):]
        self.base = self.cur
        return items

    def _lines(self, moves: list[tuple], rows: list[np.ndarray], base: int) -> Lines:
        """One Lines item of moves one after another: LINE tuples and RUNs of the C's rows."""
        parts, python = [], []  # arrays per column, in order; Python's moves waiting to become arrays
        for move in moves + [None]:
            if move is not None and move[0] == LINE:
                _, _, b, feed, tool, src, label, accel, power, dynamic = move
                python.append((rows[b - base], feed, tool, label == "G0", accel, power, dynamic, src.line, src.col))
                continue
            if python:
                parts.append([np.array(column) for column in zip(*python)])
                python = []
            if move is not None:
                _, _, lo, hi = move
                native = self.native
                parts.append([native.end[lo:hi], native.feed[lo:hi], native.tool[lo:hi], native.rapid[lo:hi] != 0,
                              native.accel[lo:hi], native.power[lo:hi], native.dynamic[lo:hi], native.line[lo:hi],
                              native.col[lo:hi]])
        end, feed, tool, rapid, accel, power, dynamic, line, col = (np.concatenate(c) for c in zip(*parts))
        points = np.concatenate([rows[moves[0][1] - base][None, :], end])
        points.flags.writeable = False
        return Lines(points, feed, tool, rapid, accel, power, dynamic, self.origin.file, line, col)

    def target(self, params: dict[str, float]) -> list[float]:
        pos, unit, off = self.pos, self.unit, self.off
        tgt = pos[:]
        for letter, value in params.items():
            i = AXIS_INDEX.get(letter)
            if i == 3:  # the extruder's moves scaled by the flow (M221)
                if self.e_relative:
                    tgt[3] = pos[3] + value * unit * self.flow
                else:
                    tgt[3] = (value * unit + off[3]) * self.flow + self.e_shift
            elif i is not None:
                tgt[i] = pos[i] + value * unit if self.relative else value * unit + off[i]
        return tgt

    def axis_missing(self, block, tgt: list[float]) -> bool:
        """An error (True) when the move changes an axis the machine cannot move; at its word."""
        for i in self.fixed:
            if tgt[i] != self.pos[i]:
                letter = AXIS_LETTERS[i]
                axis = letter.lower()
                self.fail(block, letter, f"'{self.word(block, letter)}' moves {axis}, but the machine has no "
                                         f"{axis} motor (motors: {', '.join(self.motors)})")
                return True
        return False

    def beyond_limits(self, block, tgt: list[float], speed: float, length: float | None = None) -> bool:
        """An error (True) when the move goes out of reach (at each axis word) or lasts longer than a move may (at
        its F, else the line): codegen/toolpath/limits.py. `length`: the path's (an arc's), else the straight one."""
        pos, failed = self.pos, False
        for i, letter in enumerate(AXIS_LETTERS):
            if tgt[i] != pos[i] and (message := limits.reach_error(i, tgt[i], self.reach)) is not None:
                self.fail(block, letter, message)
                failed = True
        if failed:
            return True
        if length is None:
            length = math.dist(tgt[:3], pos[:3]) or abs(tgt[3] - pos[3])
        message = limits.move_error(length, speed)
        if message is None:
            return False
        given = self.word_index(block, "F") is not None
        feed = f"'{self.word(block, 'F')}'" if given else f"the feed of {speed * 60.0:.6g} mm/min"
        self.fail(block, "F", f"{feed} {message}")
        return True

    def add_point(self, tgt: list[float]) -> int:
        """The tool goes to `tgt`: a new point; returns the index of the one before."""
        self.flat.extend(tgt)
        start, self.cur = self.cur, self.count
        self.count += 1
        self.pos = tgt
        return start

    def accel_for(self, tgt: list[float]) -> float:
        """M204's cap for a move: P with extrusion, T without, R for E alone."""
        pos = self.pos
        if tgt[3] == pos[3]:
            return self.accel_travel
        if tgt[0] == pos[0] and tgt[1] == pos[1] and tgt[2] == pos[2]:
            return self.accel_retract
        return self.accel_print

    def speed(self, feed: float, extrudes: bool) -> float:
        """A move's speed (mm/s) from its feed: times the M220 factor, at least M205's S (a move that extrudes)
        or T (any other), as Marlin's planner does."""
        return max(feed * self.speed_factor, self.min_feed if extrudes else self.min_travel_feed)

    def line_move(self, block, mode: str, params: dict[str, float]) -> None:
        tgt = self.target(params)
        if tgt == self.pos or (self.fixed and self.axis_missing(block, tgt)):
            return  # no motion: nothing to do
        if mode == "G0":
            feed, tool = self.rapid, False
        else:
            length = float(np.linalg.norm(np.subtract(tgt[:3], self.pos[:3]))) or abs(tgt[3] - self.pos[3])
            feed, tool = self.draw_speed(length), self.spindle
        feed = self.speed(feed, tgt[3] != self.pos[3])
        if self.beyond_limits(block, tgt, feed):
            return
        accel = self.accel_for(tgt)
        start = self.add_point(tgt)
        self.items.append(self.line_item(block, start, feed, tool, mode, accel))

    def line_item(self, block, start: int, feed: float, tool: bool, mode: str, accel: float) -> tuple:
        return (LINE, start, self.cur, feed, tool, self.origin.at(block.index, block.indent), mode, accel,
                self.power, self.dynamic)

    def draw_speed(self, length: float) -> float:
        """mm/s of a drawing move: its F, or in inverse time (G93) its length over the duration F says."""
        if self.inverse_feed is not None:
            return length * self.inverse_feed / 60.0
        return self.draw_feed if self.feed is None else self.feed

    def arc_move(self, block, mode: str, params: dict[str, float]) -> None:
        plane = self.plane
        u, v = plane
        letters = OFFSET_LETTERS[plane]
        name = PLANE_NAMES[plane]
        other = ({"I", "J", "K"} - set(letters)).pop()
        if other in params:
            return self.fail(block, other, f"'{other}' is not an offset in the {name} plane; use {letters[0]} "
                                           f"and {letters[1]}")
        given = [c for c in letters if c in params]
        if "R" in params and given:
            return self.fail(block, "R", f"give either R or {letters[0]}/{letters[1]}, not both")
        if "R" not in params and not given:
            return self.fail(block, mode, f"{mode} needs the centre: {letters[0]}/{letters[1]} offsets ({name} "
                                          f"plane) or R")
        for i in plane:
            if not self.movable[i]:
                axis = "xyz"[i]
                return self.fail(block, mode, f"an arc in the {name} plane moves {axis}, but the machine has no "
                                              f"{axis} motor (motors: {', '.join(self.motors)})")
        tgt = self.target(params)
        if self.fixed and self.axis_missing(block, tgt):
            return
        pos, unit = self.pos, self.unit
        start, end = (pos[u], pos[v]), (tgt[u], tgt[v])
        try:
            if "R" in params:
                circle = arcs.from_radius(start, end, params["R"] * unit, mode == "G2")
            else:
                offset = (params.get(letters[0], 0.0) * unit, params.get(letters[1], 0.0) * unit)
                circle = arcs.from_offsets(start, end, offset, mode == "G2", letters)
        except arcs.ArcError as err:
            return self.fail(block, err.letter if err.letter in params else given[0], err.message)
        along = [tgt[i] - pos[i] for i in range(3) if i not in plane]
        length = float(np.hypot(circle.radius * abs(circle.sweep), np.linalg.norm(along)))
        if (message := arcs.too_long(circle, length, "R" in params and params["R"] < 0.0)) is not None:
            return self.fail(block, "R" if "R" in params else given[0], message)
        feed = self.speed(self.draw_speed(length), tgt[3] != pos[3])
        if self.beyond_limits(block, tgt, feed, length):
            return
        tool = self.spindle
        accel = self.accel_travel if tgt[3] == pos[3] else self.accel_print
        start_index = self.add_point(tgt)
        self.items.append((ARC, start_index, self.cur, circle, plane, feed, tool, self.source(block), mode, accel,
                           self.power, self.dynamic))

    def set_position(self, block, params: dict[str, float]) -> bool | None:
        """G92: the program position of the named axes becomes the given values (the machine stays)."""
        given = [i for i, letter in enumerate(AXIS_LETTERS) if letter in params]
        if not given:
            self.fail(block, "G92", "G92 needs the axis words to set (X, Y, Z, E)")
            return False
        for i in given:
            self.off[i] = self.pos[i] - params[AXIS_LETTERS[i]] * self.unit
        if 3 in given:  # the program's E there is the machine's: the flow scales moves from here on
            self.e_shift = self.pos[3] * (1.0 - self.flow)
        return None

    def home(self, block, params: dict[str, float]) -> bool | None:
        """G28 [X] [Y] [Z] (values ignored; none: every axis the machine has): those axes go home, where
        their G92 offsets are cleared (as Marlin). A delta always homes all three."""
        named = [i for i in range(3) if "XYZ"[i] in params]
        if self.kinematics == "delta" or not named:
            named = [i for i in range(3) if self.movable[i]]
        home = self.home_point
        tgt = self.pos[:]
        axes = []
        for i in named:
            axis = "xyz"[i]
            if not self.movable[i]:
                if self.pos[i] != home[i]:
                    self.fail(block, "XYZ"[i], f"G28 homes {axis}, but the machine has no {axis} motor "
                                               f"(motors: {', '.join(self.motors)})")
                    return False
                continue
            tgt[i] = home[i]
            self.off[i] = 0.0
            axes.append(axis)
        if axes:
            self.add_point(tgt)
            self.items.append((HOME, tuple(axes), self.cur, self.source(block)))
        return None
