"""Forked workers that run inputs in-process under a time limit of CPU seconds (SIGPROF raising Hang: a worker
that shares its core with other work is not cut short; faulthandler's watchdog dumps the stack and exits, by the
wall clock, where a C loop never returns to Python or the worker waits without working; the parent kills after
that) and a memory limit (RLIMIT_AS). Forked from a parent that has imported codegen, so no worker imports it again; a worker
that dies is replaced, and so is one that hit a limit (its state may be half changed)."""

from __future__ import annotations

import faulthandler
import multiprocessing
import os
import resource
import signal
import tempfile
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator

from tests.fuzzing.outcomes import HANG, MEMORY, Hang, Outcome, classify, died

WALL_FACTOR = 10  # the wall clock's limit, in CPU time limits: a worker may get a tenth of a core
WATCHDOG_S = 3.0  # after the wall's limit: faulthandler dumps the stack and ends the worker
KILL_S = 6.0  # after the wall's limit: the parent kills the worker
GiB = 1 << 30


def _alarm(signum, frame) -> None:
    raise Hang()


def _serve(run: Callable[[Any], int], conn: Connection, folder: Path, dump_path: Path, time_limit: float,
           memory_bytes: int) -> None:
    """A worker's loop: receive (key, item), send (key, outcome), until None or the pipe closes."""
    os.chdir(folder)
    os.environ["PRINTER_CODEGEN_JOBS"] = "1"  # codegen/overlap.py: the front end in this process, not a child
    resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    dump = open(dump_path, "w+")
    faulthandler.enable(dump)  # a segfault's stack goes to the dump, for the parent's signature
    signal.signal(signal.SIGPROF, _alarm)
    while True:
        try:
            message = conn.recv()
        except EOFError:
            return
        if message is None:
            return
        key, item = message
        os.ftruncate(dump.fileno(), 0)
        os.lseek(dump.fileno(), 0, os.SEEK_SET)
        faulthandler.dump_traceback_later(WALL_FACTOR * time_limit + WATCHDOG_S, exit=True, file=dump)
        signal.setitimer(signal.ITIMER_PROF, time_limit)  # CPU seconds, this process's threads all counted
        outcome = classify(lambda: run(item), time_limit)
        try:
            signal.setitimer(signal.ITIMER_PROF, 0)
        except Hang:  # the alarm went off just as the input finished
            pass
        faulthandler.cancel_dump_traceback_later()
        conn.send((key, outcome))


@dataclass(eq=False)
class _Worker:
    process: multiprocessing.Process
    conn: Connection
    dump_path: Path
    key: Any = None
    busy: bool = False
    deadline: float = 0.0


class WorkerPool:
    """`jobs` forked workers running `run(item)` (returns an exit code) for the items of `imap`."""

    def __init__(self, run: Callable[[Any], int], jobs: int = 2, time_limit: float = 20.0,
                 memory_bytes: int = 3 * GiB):
        self.run, self.time_limit, self.memory_bytes = run, time_limit, memory_bytes
        self._folder = tempfile.TemporaryDirectory(prefix="fuzz-workers-")
        self._context = multiprocessing.get_context("fork")
        self.workers = [self._start(n) for n in range(jobs)]

    def _start(self, slot: int) -> _Worker:
        folder = Path(self._folder.name) / f"worker-{slot}"
        folder.mkdir(exist_ok=True)
        parent, child = self._context.Pipe()
        dump_path = folder / "faulthandler.txt"
        process = self._context.Process(target=_serve, daemon=True, args=(
            self.run, child, folder, dump_path, self.time_limit, self.memory_bytes))
        process.start()
        child.close()
        return _Worker(process, parent, dump_path)

    def _replace(self, worker: _Worker) -> None:
        if worker.process.is_alive():
            worker.process.kill()
        worker.process.join()
        worker.conn.close()
        slot = self.workers.index(worker)
        self.workers[slot] = self._start(slot)

    def _dead(self, worker: _Worker, timed_out: bool) -> Outcome:
        if worker.process.is_alive():
            worker.process.kill()
        worker.process.join()
        dump = worker.dump_path.read_text(errors="replace") if worker.dump_path.exists() else ""
        return died(worker.process.exitcode, dump, timed_out)

    def _finished(self, worker: _Worker, now: float) -> Outcome | None:
        """The worker's outcome if it has one (its answer, its death, its deadline passed), else None."""
        if worker.conn.poll():
            try:
                return worker.conn.recv()[1]
            except (EOFError, OSError):
                return self._dead(worker, timed_out=False)
        if not worker.process.is_alive():
            return self._dead(worker, timed_out=False)
        if now > worker.deadline:
            return self._dead(worker, timed_out=True)
        return None

    def imap(self, items: Iterable[tuple[Any, Any]]) -> Iterator[tuple[Any, Outcome]]:
        """(key, outcome) for every (key, item), as they finish; items are taken only as workers are free."""
        pending = iter(items)
        exhausted = False
        while True:
            for worker in self.workers:
                if not worker.busy and not exhausted:
                    try:
                        worker.key, item = next(pending)
                    except StopIteration:
                        exhausted = True
                        break
                    worker.conn.send((worker.key, item))
                    worker.busy, worker.deadline = True, time.monotonic() + WALL_FACTOR * self.time_limit + KILL_S
            busy = [w for w in self.workers if w.busy]
            if not busy:
                return
            wait([w.conn for w in busy] + [w.process.sentinel for w in busy],
                 timeout=max(0.0, min(w.deadline for w in busy) - time.monotonic()))
            now = time.monotonic()
            for worker in busy:
                outcome = self._finished(worker, now)
                if outcome is None:
                    continue
                key, worker.busy = worker.key, False
                if outcome.kind in (HANG, MEMORY) or not worker.process.is_alive():
                    self._replace(worker)
                yield key, outcome

    def close(self) -> None:
        for worker in self.workers:
            if worker.process.is_alive():
                try:
                    worker.conn.send(None)
                except OSError:
                    pass
                worker.process.join(timeout=2)
            if worker.process.is_alive():
                worker.process.kill()
                worker.process.join()
        self._folder.cleanup()

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
