"""Faults on the line from the host to the firmware, for `verify --stream` and its tests: the host's frames as
they would arrive over a bad cable or from a stalled host. `Faulty` wraps a HostLink and has its interface
(and its figures: stats, outcome, position and the rest are the wrapped link's)."""

from __future__ import annotations

from dataclasses import dataclass, field

from codegen.link import protocol as p
from codegen.link.host import HostLink


@dataclass(frozen=True)
class LineFaults:
    corrupt_bytes: frozenset[int] = frozenset()  # bytes on the line (counted from 0) that arrive with bits flipped
    drop_bytes: frozenset[int] = frozenset()  # bytes that never arrive
    duplicate_frames: frozenset[int] = frozenset()  # frames (counted from 0) that arrive twice
    swap_frames: frozenset[int] = frozenset()  # frame k arrives after the next frame the host sends
    pause: tuple[float, float] | None = None  # (from s, for s): the host sends nothing then (a stalled host)

    def describe(self) -> str:
        parts = [f"{name.replace('_', ' ')} {sorted(v)}" for name, v in vars(self).items() if v and name != "pause"]
        if self.pause:
            parts.append(f"a host pause of {self.pause[1]} s at {self.pause[0]} s")
        return ", ".join(parts) or "none"


@dataclass
class Faulty:
    """A HostLink whose frames meet `faults` on their way (the link's own figures count what it sent)."""

    link: HostLink
    faults: LineFaults = field(default_factory=LineFaults)

    def __post_init__(self):
        self._frames = 0
        self._bytes = 0
        self._held: list[bytes] = []  # a frame kept back to swap with the next
        self._parser = p.Parser()

    def __getattr__(self, name: str):
        return getattr(self.link, name)  # only for what Faulty does not define itself

    def wake_at(self) -> float | None:
        wake = self.link.wake_at()
        pause = self.faults.pause
        if pause is not None and wake is not None and pause[0] <= wake < pause[0] + pause[1]:
            return pause[0] + pause[1]
        return wake

    def receive(self, data: bytes, now: float) -> None:
        self.link.receive(data, now)

    def transmit(self, now: float) -> bytes:
        pause = self.faults.pause
        if pause is not None and pause[0] <= now < pause[0] + pause[1]:
            return b""
        out = bytearray()
        for f in self._parser.feed(self.link.transmit(now)):
            data = p.frame(f.kind, f.seq, f.payload)
            k = self._frames
            self._frames += 1
            copies = [data, data] if k in self.faults.duplicate_frames else [data]
            if k in self.faults.swap_frames:
                self._held += copies
                continue
            for c in copies + self._held:
                out += self._bytes_out(c)
            self._held = []
        return bytes(out)

    def _bytes_out(self, data: bytes) -> bytes:
        out = bytearray()
        for b in data:
            k = self._bytes
            self._bytes += 1
            if k in self.faults.drop_bytes:
                continue
            out.append(b ^ 0x10 if k in self.faults.corrupt_bytes else b)
        return bytes(out)
