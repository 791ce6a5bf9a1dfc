"""`printer-codegen stream`: a HostLink session over a real serial port (pyserial), in real time, with a progress
bar (tqdm) of the stream bytes the firmware has acknowledged and, once the job has started, the firmware's STATUS
beside it (asked for every STATUS_EVERY_S: state, ring fill, positions, heaters). Ctrl-C sends ABORT and waits
for the firmware to report where it stopped (a second Ctrl-C stops waiting). A firmware with feed hold takes
Grbl's keys from the terminal: `!` hold, `~` resume, and `-` / `+` the feed override by 10 %."""

from __future__ import annotations

import os
import select
import signal
import sys
import time
from contextlib import contextmanager

from codegen.errors import BuildError
from codegen.link.host import HostLink
from codegen.link.protocol import FEED_DOWN, FEED_UP, HOLD, RESUME, Status
from codegen.tables.hold import F_ONE

ABORT_WAIT_S = 3.0  # after Ctrl-C: how long the firmware has to answer ABORTED
READ_SLICE_S = 0.002  # the longest a read waits before the session looks at its timers again
BOOT_S = 3.0  # an Arduino resets when its port opens, and its bootloader waits a second or two: HELLO that long
LATENCY_S = 0.004  # a USB serial adapter's answer delay beyond the byte times (USB frames of 1 ms, buffering)
STATUS_EVERY_S = 0.5  # with the progress bar: a STATUS asked for this often while the job plays
HOLD_KEYS = {"!": HOLD, "~": RESUME, "-": FEED_DOWN, "+": FEED_UP}  # Grbl's feed hold and cycle start, and ours


@contextmanager
def terminal_keys(enabled: bool):
    """A function that returns the keys typed since its last call (without Enter) while the terminal is in
    cbreak mode; a function that returns none where stdin is not a terminal or not `enabled`."""
    if not enabled or not sys.stdin.isatty():
        yield lambda: ""
        return
    import termios
    import tty

    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    tty.setcbreak(fd)

    def typed() -> str:
        out = ""
        while select.select([fd], [], [], 0)[0]:
            out += os.read(fd, 64).decode(errors="ignore")
        return out

    try:
        yield typed
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def send_hold_keys(link: HostLink, typed: str) -> None:
    """The hold keys among `typed`, in order, as the link's requests."""
    for key in typed:
        if key in HOLD_KEYS:
            link.feed(HOLD_KEYS[key])


def open_port(port: str, baud: int):
    import serial  # pyserial: imported here so that the other verbs never need it

    try:
        return serial.Serial(port, baud, timeout=0, write_timeout=5)
    except (serial.SerialException, OSError) as error:
        raise BuildError(f"cannot open {port} at {baud} baud: {error}") from None


def status_line(status: Status, motors: tuple[str, ...], heaters: tuple[str, ...], laser_top: int = 0) -> str:
    """A STATUS answer in a few words: state, ring fill, each motor's steps since START, each heater's temperature
    and target, the laser's power (in % of `laser_top`, its PWM's counts of full power)."""
    parts = [status.state, f"ring {status.fill} B", " ".join(f"{m} {p:+d}" for m, p in zip(motors, status.position))]
    parts += [f"{name} {temp:.1f}/{target:g} degC" for name, (temp, target) in zip(heaters, status.heaters)]
    if status.laser is not None and laser_top:
        parts.append(f"laser {100 * status.laser / laser_top:.1f} %")
    if status.feed is not None and status.state == "playing":
        parts.append("held" if status.feed == 0 else f"feed {100 * status.feed / F_ONE:.0f} %")
    return ", ".join(parts)


def run(link: HostLink, port, total_bytes: int, progress: bool = True, motors: tuple[str, ...] = (),
        keys=lambda: "") -> bool:
    """Drive `link` over the open `port` until the session ends; True when Ctrl-C sent ABORT. With `progress`, the
    bar shows the firmware's STATUS once the job has started (`motors`: their names, in the firmware's order).

    Ctrl-C is caught by a signal handler and acted on between the session's steps: a KeyboardInterrupt raised
    anywhere in them could cut a frame short on the line or drop an answer the link was parsing. The first sends
    ABORT; a second, or no end within ABORT_WAIT_S, stops waiting for the firmware. `keys` returns what was
    typed since its last call (terminal_keys): the hold keys become the link's requests once the job started."""
    from tqdm import tqdm

    presses: list[float] = []  # when Ctrl-C was pressed
    previous = signal.signal(signal.SIGINT, lambda signum, frame: presses.append(time.monotonic()))
    start = time.monotonic()
    aborting = False
    status_due, shown = 0.0, None
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
            typed = keys()
            if typed and link.started_at is not None:
                send_hold_keys(link, typed)
            if progress and link.started_at is not None and now >= status_due:
                link.request_status()
                status_due = now + STATUS_EVERY_S
            out = link.transmit(now)
            if out:
                port.write(out)
            wake = link.wake_at()
            port.timeout = READ_SLICE_S if wake is None else min(max(wake - now, 0.0), READ_SLICE_S)
            data = port.read(max(1, port.in_waiting))
            if data:
                link.receive(data, time.monotonic() - start)
            if link.status is not shown:
                shown = link.status
                # redrawn: the bytes may all be out
                bar.set_postfix_str(status_line(shown, motors, link.heaters, link.laser_top))
            bar.update(link.stats.data_bytes - bar.n)
    finally:
        signal.signal(signal.SIGINT, previous)
        bar.close()
    return aborting
