"""`printer-codegen stream`: a HostLink session over a real serial port (pyserial), in real time, with a progress
bar (tqdm) of the stream bytes the firmware has acknowledged. Ctrl-C sends ABORT and waits for the firmware
to report where it stopped (a second Ctrl-C stops waiting)."""

from __future__ import annotations

import signal
import time

from codegen.errors import BuildError
from codegen.link.host import HostLink

ABORT_WAIT_S = 3.0  # after Ctrl-C: how long the firmware has to answer ABORTED
READ_SLICE_S = 0.002  # the longest a read waits before the session looks at its timers again
BOOT_S = 3.0  # an Arduino resets when its port opens, and its bootloader waits a second or two: HELLO that long
LATENCY_S = 0.004  # a USB serial adapter's answer delay beyond the byte times (USB frames of 1 ms, buffering)


def open_port(port: str, baud: int):
    import serial  # pyserial: imported here so that the other verbs never need it

    try:
        return serial.Serial(port, baud, timeout=0, write_timeout=5)
    except (serial.SerialException, OSError) as error:
        raise BuildError(f"cannot open {port} at {baud} baud: {error}") from None


def run(link: HostLink, port, total_bytes: int, progress: bool = True) -> bool:
    """Drive `link` over the open `port` until the session ends; True when Ctrl-C sent ABORT.

    Ctrl-C is caught by a signal handler and acted on between the session's steps: a KeyboardInterrupt raised
    anywhere in them could cut a frame short on the line or drop an answer the link was parsing. The first sends
    ABORT; a second, or no end within ABORT_WAIT_S, stops waiting for the firmware."""
    from tqdm import tqdm

    presses: list[float] = []  # when Ctrl-C was pressed
    previous = signal.signal(signal.SIGINT, lambda signum, frame: presses.append(time.monotonic()))
    start = time.monotonic()
    aborting = False
    bar = tqdm(total=total_bytes, unit="B", unit_scale=True, desc="streaming", disable=not progress,
               dynamic_ncols=True)
    try:
        while not link.done:
            if presses and not aborting:
                aborting = True
                link.abort()
            if len(presses) > 1 or (aborting and time.monotonic() > presses[0] + ABORT_WAIT_S):
                break
            now = time.monotonic() - start
            out = link.transmit(now)
            if out:
                port.write(out)
            wake = link.wake_at()
            port.timeout = READ_SLICE_S if wake is None else min(max(wake - now, 0.0), READ_SLICE_S)
            data = port.read(max(1, port.in_waiting))
            if data:
                link.receive(data, time.monotonic() - start)
            bar.update(link.stats.data_bytes - bar.n)
    finally:
        signal.signal(signal.SIGINT, previous)
        bar.close()
    return aborting
