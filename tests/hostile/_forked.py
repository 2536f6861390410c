"""One forked child per case, for the drivers of the hostile tables and the command-line
tests (`_hostile_driver`, `test_hostile_cli`, `tests/test_cli.py`).

Those drivers run as `python -c` scripts in a process that imported voxax once (without
starting XLA); each case forks from it, so a crash, a hang or leftover state stays in the
case's own process. The scripts import this module (its folder on `PYTHONPATH`:
`FOLDER`).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
import traceback

FOLDER = os.path.dirname(os.path.abspath(__file__))


def _exit_code(exit: SystemExit) -> int:
    """The status `sys.exit(x)` gives: an int as is, None 0, anything else 1 (a message
    string is printed to stderr)."""
    if isinstance(exit.code, int):
        return exit.code
    if isinstance(exit.code, str):
        print(exit.code, file=sys.stderr)
    return 0 if exit.code is None else 1


def run_forked(body, limit: float | None = None):
    """Runs `body()` in a forked child with its own stdout and stderr; the child exits with
    the int `body` returns (a `SystemExit` gives its status; any other exception prints its
    traceback to stderr and gives 1). Returns `(exit status, seconds, stdout, stderr)`;
    the status is None when the child ran past `limit` seconds (it is killed: a hang)."""
    pipes = [os.pipe(), os.pipe()]
    start = time.monotonic()
    pid = os.fork()
    if pid == 0:
        os.dup2(pipes[0][1], 1)
        os.dup2(pipes[1][1], 2)
        try:
            code = body()
        except SystemExit as exit:
            code = _exit_code(exit)
        except BaseException:
            traceback.print_exc()
            code = 1
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    for _, w in pipes:
        os.close(w)
    # the pipes are read while the child runs: a child that fills one must not block
    texts = [b"", b""]

    def drain(i, fd):
        with os.fdopen(fd, "rb") as fh:
            texts[i] = fh.read()

    readers = [threading.Thread(target=drain, args=(i, r)) for i, (r, _) in enumerate(pipes)]
    for t in readers:
        t.start()
    status = None
    if limit is None:
        _, status = os.waitpid(pid, 0)
    else:
        while time.monotonic() - start < limit:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            time.sleep(0.02)
        else:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            status = None
    for t in readers:
        t.join()
    code = None if status is None else os.waitstatus_to_exitcode(status)
    return code, time.monotonic() - start, *(t.decode("utf-8", "replace") for t in texts)
