"""Progress bars for the stages that take long (plan, compile, simulate, stream): a tqdm bar on stderr with the
stage's name, its share done and an ETA, or nothing.

Bars are off until the CLI turns them on (`enable`: where stderr is a terminal, unless --quiet), so the library
and the tests that call it stay silent. A bar appears once its stage has run PRINTER_CODEGEN_PROGRESS_DELAY
seconds (default 2; 0 shows every bar at once, as the tests do) and goes when its stage ends. Callers move a bar
per window, file or poll, never per step.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Callable

DELAY_ENV = "PRINTER_CODEGEN_PROGRESS_DELAY"
DEFAULT_DELAY_S = 2.0
POLL_S = 0.25  # how often run_watched reads a running process's progress

_on = False


def enable(on: bool) -> None:
    """Bars on or off, for the whole process."""
    global _on
    _on = on


def enabled() -> bool:
    """Bars are on (a terminal on stderr, no --quiet)."""
    return _on


def stage(name: str, total: float, unit: str | None = None, digits: int = 0):
    """The bar of stage `name`, from 0 to `total`, to use as a context manager: the percentage, then `n/total
    unit` with `digits` decimals (none with `unit` None), elapsed time, ETA and any postfix. While bars are off,
    a stand-in with the same methods that does nothing."""
    if not _on:
        return _Off(total)
    from tqdm import tqdm  # here: a run without bars never imports it

    count = "" if unit is None else f" {{n:.{digits}f}}/{{total:.{digits}f}} {unit}"
    return tqdm(total=total, desc=name, file=sys.stderr, leave=False, dynamic_ncols=True,
                delay=float(os.environ.get(DELAY_ENV, DEFAULT_DELAY_S)),
                bar_format="{desc}: {percentage:3.0f}%|{bar}|" + count + " [{elapsed}<{remaining}{postfix}]")


def move_to(bar, n: float) -> None:
    """The bar at `n` (at most its total)."""
    bar.update(min(n, bar.total) - bar.n)


class _Off:
    """A bar while bars are off."""

    disable = True

    def __init__(self, total: float):
        self.n, self.total = 0, total

    def __enter__(self) -> _Off:
        return self

    def __exit__(self, *exc) -> None:
        pass

    def update(self, n: float = 1) -> None:
        pass

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        pass

    def close(self) -> None:
        pass


def run_watched(cmd: list[str], bar, done: Callable[[Path], float | None]) -> subprocess.CompletedProcess:
    """subprocess.run(cmd, capture_output=True, text=True), with `bar` moved to done(path of the process's stdout
    so far) every POLL_S while it runs; stdin is /dev/null. With the bar off, simply subprocess.run."""
    if bar.disable:
        return subprocess.run(cmd, stdin=subprocess.DEVNULL, capture_output=True, text=True)
    with tempfile.TemporaryDirectory(prefix="printer-codegen-run-") as tmp:
        out_path, err_path = Path(tmp) / "stdout", Path(tmp) / "stderr"
        with open(out_path, "wb") as out, open(err_path, "wb") as err:
            process = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=out, stderr=err)
            try:
                while True:
                    try:
                        process.wait(timeout=POLL_S)
                        break
                    except subprocess.TimeoutExpired:
                        n = done(out_path)
                        if n is not None:
                            move_to(bar, n)
            finally:
                if process.poll() is None:  # an exception here (Ctrl-C): the process goes too
                    process.kill()
                    process.wait()
        return subprocess.CompletedProcess(cmd, process.returncode, out_path.read_text(errors="replace"),
                                           err_path.read_text(errors="replace"))


def tail(path: Path, size: int = 512) -> bytes:
    """The last `size` bytes of a file another process is writing (b"" before it exists)."""
    try:
        with open(path, "rb") as file:
            file.seek(0, os.SEEK_END)
            file.seek(max(file.tell() - size, 0))
            return file.read()
    except OSError:
        return b""
