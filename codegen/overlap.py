"""Overlap: a generator run in a child process on another core, its items handed over through a pipe as they
come (the front end reads and cuts the program while the main process plans and checks what it has).

The child is forked, so it starts with the parent's state and needs nothing pickled but its items; an
exception in it is raised again in the parent, as it would have been raised there. The child may run up to
AHEAD items ahead (a stretch that is slow to read does not stall the parent), then waits: memory stays
bounded. Where only one core is ours (or
PRINTER_CODEGEN_JOBS=1, or no fork), the generator runs in the parent: the items are the same either way.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
import traceback
from typing import Callable, Iterator

_ITEM, _DONE, _FAILED = range(3)
AHEAD = 6


def cores() -> int:
    """The cores this process may run on, or 1 where PRINTER_CODEGEN_JOBS=1 says so."""
    if os.environ.get("PRINTER_CODEGEN_JOBS") == "1":
        return 1
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def overlapped(produce: Callable[[], Iterator]) -> Iterator:
    """The items of `produce()`, made in a child process where another core is free."""
    if cores() < 2 or "fork" not in multiprocessing.get_all_start_methods():
        yield from produce()
        return
    context = multiprocessing.get_context("fork")
    queue = context.Queue(maxsize=AHEAD)
    child = context.Process(target=_serve, args=(queue, produce), daemon=True)
    child.start()
    try:
        while True:
            kind, payload = queue.get()
            if kind == _ITEM:
                yield payload
            elif kind == _DONE:
                return
            else:
                raise payload
    finally:
        child.join(timeout=1.0)
        if child.is_alive():  # the parent stopped early (an error): the child waits on a full pipe
            child.terminate()
            child.join()


def _serve(queue, produce: Callable[[], Iterator]) -> None:
    try:
        for item in produce():
            queue.put((_ITEM, item))
        queue.put((_DONE, None))
    except BaseException as exc:  # noqa: BLE001 - every failure goes to the parent, as it is
        try:
            pickle.dumps(exc)
        except Exception:  # an exception that does not pickle: its traceback, as text
            exc = RuntimeError("".join(traceback.format_exception(exc)))
        queue.put((_FAILED, exc))
    finally:
        queue.close()
        queue.join_thread()
