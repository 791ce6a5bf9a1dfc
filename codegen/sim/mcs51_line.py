"""The host-to-8051 serial line of a simulated stream (codegen/sim/mcs51_link.py): when each byte completes on a
real 8N1 line and when the firmware read SBUF, counted as they come. A byte is late (lost on a real UART) when it
completed before the firmware read the one ahead of it; bytes whose pair is judged are dropped, so the line holds
only the bytes not yet read, whatever the stream's length."""

from __future__ import annotations

from collections import deque


class UartLine:
    def __init__(self, byte_clocks: int):
        self.byte_clocks = byte_clocks  # a byte's 10 bit times at the firmware's rate
        self.sent = 0  # bytes put on the line
        self.read = 0  # SBUF reads
        self.last_arrival = 0  # when the latest byte sent completes
        self.late = 0
        self._arrivals: deque[int] = deque()  # the completions of bytes 1.. not yet judged
        self._reads: deque[int] = deque()  # reads whose next byte is not yet judged
        self._judged = 0  # pairs judged: byte k + 1's completion against the read of byte k
        self._first: int | None = None  # when the first byte completes

    def send(self, count: int, now: int) -> None:
        """`count` bytes written at clock `now`, back to back after those before."""
        for _ in range(count):
            self.last_arrival = max(self.last_arrival, now) + self.byte_clocks
            if self.sent:
                self._arrivals.append(self.last_arrival)
            else:
                self._first = self.last_arrival
            self.sent += 1

    def reading(self, clock: int) -> None:
        self._reads.append(clock)
        self.read += 1

    def waiting(self) -> bool:
        """Bytes wait in the line's FIFO beyond the one the UART takes next."""
        return self.read < self.sent - 1

    def judge(self, now: int) -> None:
        """Count the pairs whose byte has completed on the line by `now` and whose read ahead of it is known."""
        while self._arrivals and self._reads and self._arrivals[0] + self.byte_clocks <= now:
            self.late += self._reads.popleft() > self._arrivals.popleft()
            self._judged += 1

    def lost_bytes(self, now: int) -> int:
        """Bytes a real UART would have lost by `now`: late ones (and, where s51 merged two, reads missing; a byte
        that completed less than a byte time ago may be unread)."""
        self.judge(now)
        first = int(self._first is not None and self._first + self.byte_clocks <= now)
        done = first + self._judged + sum(1 for t in self._arrivals if t + self.byte_clocks <= now)
        return max(self.late, done - self.read)
