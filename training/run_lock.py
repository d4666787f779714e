"""One run a folder: `python -m training run` holds its output folder for as long as it trains,
so that a second run on the same folder (a second grid over the same cells, a command typed
twice) stops at once instead of writing the same checkpoints.

The hold is an advisory lock (flock) on OUT/.run-lock, which holds the holder's process id. The
operating system drops it when the process ends, however it ends (SIGKILL, a lost terminal), so
there is never a stale lock to clear by hand. POSIX only, as the grid's own process handling.
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

LOCK_FILE = ".run-lock"
"""The file in a run's folder that its run holds."""
RUN_HELD = 75
"""Exit status of a run whose folder another run holds (EX_TEMPFAIL: try again later)."""


class RunFolderHeld(RuntimeError):
    """The run's folder is held by another process."""


@contextmanager
def holding_run_folder(out: Path) -> Iterator[None]:
    """Hold `out` (made if absent) while the block runs; raises RunFolderHeld, naming the holder's
    process id, where another process holds it."""
    out.mkdir(parents=True, exist_ok=True)
    with open(out / LOCK_FILE, "a+") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            raise RunFolderHeld(f"{out} is in use by another run (process {holder}); one run a folder at a "
                                "time: wait for it, or stop it (SIGTERM keeps its checkpoint)") from None
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        yield
