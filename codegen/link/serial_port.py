"""`printer-codegen stream`: a HostLink session over a real serial port (pyserial), in real time, with a progress
bar (tqdm) of the stream bytes the firmware has acknowledged. Ctrl-C sends ABORT and waits for the firmware
to report where it stopped."""

from __future__ import annotations

import time

from codegen.errors import BuildError
from codegen.link.host import HostLink

ABORT_WAIT_S = 3.0  # after Ctrl-C: how long the firmware has to answer ABORTED
READ_SLICE_S = 0.002  # the longest a read waits before the session looks at its timers again


def open_port(port: str, baud: int):
    import serial  # pyserial: imported here so that the other verbs never need it

    try:
        return serial.Serial(port, baud, timeout=0, write_timeout=5)
    except (serial.SerialException, OSError) as error:
        raise BuildError(f"cannot open {port} at {baud} baud: {error}") from None


def run(link: HostLink, port, total_bytes: int, progress: bool = True) -> bool:
    """Drive `link` over the open `port` until the session ends; True when it was interrupted (Ctrl-C)."""
    from tqdm import tqdm

    start = time.monotonic()
    interrupted = False
    abort_deadline = None
    bar = tqdm(total=total_bytes, unit="B", unit_scale=True, desc="streaming", disable=not progress,
               dynamic_ncols=True)
    try:
        while not link.done:
            try:
                now = time.monotonic() - start
                out = link.transmit(now)
                if out:
                    port.write(out)
                wake = link.wake_at()
                wait = READ_SLICE_S if wake is None else min(max(wake - now, 0.0), READ_SLICE_S)
                port.timeout = wait
                data = port.read(max(1, port.in_waiting))
                if data:
                    link.receive(data, time.monotonic() - start)
                bar.update(link.stats.data_bytes - bar.n)
                if abort_deadline is not None and time.monotonic() > abort_deadline:
                    break
            except KeyboardInterrupt:
                if interrupted:
                    break
                interrupted = True
                link.abort()
                abort_deadline = time.monotonic() + ABORT_WAIT_S
    finally:
        bar.close()
    return interrupted
