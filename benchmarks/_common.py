"""Helpers shared by the benchmark workers (`_voxax.py`, `_peer.py`).

Imported by both worker processes, which run in different virtual environments, so it
depends on the standard library only. The driver (`run.py`) talks to a worker with one
JSON object per line: requests on the worker's stdin, replies on its stdout. Everything
else a worker (or a library it loads) prints goes to stderr.
"""

from __future__ import annotations

import ctypes
import gc
import json
import os
import sys
import time
import traceback

__all__ = ["proc_status_kib", "reset_peak_rss", "trim_memory", "timed", "op_handlers", "serve"]


def proc_status_kib(field: str) -> int | None:
    """A `VmRSS`/`VmHWM`-style field of /proc/self/status in KiB (None where absent)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def reset_peak_rss() -> bool:
    """Resets VmHWM (the peak RSS) to the current RSS; False where the kernel refuses."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def trim_memory() -> None:
    """Collects garbage and hands freed heap memory back to the OS (glibc)."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def timed(fn) -> tuple[float, object]:
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def op_handlers(ops: dict, build) -> dict:
    """The `prepare`/`run`/`release` handlers both workers share.

    `build(op, n)` returns `(pre, fn)`: `pre` (or None) runs untimed before each timed
    call of `fn`. Prepared ops live in `ops` until released.
    """

    def prepare(op, n):
        ops[op] = build(op, n)
        return {}

    def run(op):
        pre, fn = ops[op]
        if pre is not None:
            pre()
        seconds, out = timed(fn)
        del out
        return {"seconds": seconds}

    def release(op=None):
        if op is None:
            ops.clear()
        else:
            ops.pop(op, None)
        trim_memory()
        return {}

    return {"prepare": prepare, "run": run, "release": release}


def serve(handlers: dict) -> None:
    """Answers JSON requests `{"cmd": name, **kwargs}` read from stdin, one per line."""
    proto = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)  # stray prints, also from C code, go to stderr
    sys.stdout = sys.stderr
    for line in sys.stdin:
        if not line.strip():
            continue
        request = json.loads(line)
        cmd = request.pop("cmd")
        if cmd == "exit":
            break
        try:
            reply = {"ok": True, **(handlers[cmd](**request) or {})}
        except Exception as err:  # reported to the driver, which decides
            reply = {"ok": False, "error": f"{type(err).__name__}: {err}", "traceback": traceback.format_exc()}
        reply["rss_mib"] = (proc_status_kib("VmRSS") or 0) / 1024
        proto.write(json.dumps(reply) + "\n")
        proto.flush()
