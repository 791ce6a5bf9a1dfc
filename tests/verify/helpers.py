"""The verify tests' shared parts (tests/verify/): the 8051 hold plotter's job file (test_hold_mcs51.py,
test_hold_mcs51_stream.py) and the scripted host that asks for STATUS at given cycles (test_hold_stream.py,
test_hold_mcs51_stream.py)."""

from __future__ import annotations

from pathlib import Path

from codegen.verify.hold_runs import Scripted

HOLD51 = """name: hold51
target: mcs51
board: seed-51
machine:
  kinematics: cartesian
  steppers:
    x: {{steps_per_mm: 40, max_velocity: {v}, max_accel: {a}, range: [0, 200]}}
    y: {{steps_per_mm: 40, max_velocity: {v}, max_accel: {a}, range: [0, 200]}}
{hold}
program:
  feed: {feed}
  shapes:
    - line: {{from: [0, 0], to: [20, 0]}}
    - line: {{from: [20, 0], to: [20, 15]}}
    - arc: {{center: [10, 15], radius: 10, start: 0, sweep: 180}}
    - line: {{from: [0, 15], to: [0, 0]}}
"""
HOLD = "  feed_hold: {}"


def job_file(folder: Path, hold: str = HOLD, velocity: int = 40, accel: int = 1000) -> Path:
    """A plotter at its motors' full speed (1,600 steps/s by default), 2.15 s of lines and a half circle."""
    path = folder / "hold51.yaml"
    path.write_text(HOLD51.format(hold=hold, v=velocity, a=accel, feed=velocity * 60))
    return path


class Watched(Scripted):
    """The scripted host that also asks for a STATUS at given cycles and keeps every answer."""

    def __init__(self, link, script, f_cpu, asks):
        super().__init__(link, script, f_cpu)
        self.asks, self.answers = list(asks), []

    def wake_at(self):
        times = [t for t in (super().wake_at(), self.asks[0] / self.f_cpu if self.asks else None) if t is not None]
        return min(times) if times else None

    def transmit(self, now):
        if self.asks and now * self.f_cpu >= self.asks[0] - 1 and self.link.ident is not None:
            self.asks.pop(0)
            self.link.request_status()
        return super().transmit(now)

    def receive(self, data, now):
        before = self.link.status
        super().receive(data, now)
        if self.link.status is not before:
            self.answers.append((now, self.link.status))
