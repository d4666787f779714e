"""Stopping a training run cleanly: SIGINT (Ctrl-C) or SIGTERM asks the loop to end its batch
step and write a whole checkpoint first (training.train)."""

from __future__ import annotations

import signal
import threading
from pathlib import Path
from typing import Any


class TrainingStopped(Exception):
    """Training stopped by SIGINT (Ctrl-C) or SIGTERM after writing a whole checkpoint."""

    def __init__(self, signal_name: str, env_step: int, out_dirs: list[Path]) -> None:
        if len(out_dirs) == 1:
            where = (f"a whole checkpoint is in {out_dirs[0]} (`python -m training train --resume {out_dirs[0]}`, "
                     "or the same `run` command, goes on from it)")
        else:
            where = (f"a whole checkpoint of each seed is in {', '.join(map(str, out_dirs))} (the same `run` "
                     "command goes on from them)")
        super().__init__(f"stopped by {signal_name} at environment step {env_step:,}: {where}")
        self.env_step = env_step


class StopRequests:
    """While active, SIGINT (Ctrl-C) and SIGTERM (`kill PID`) only ask the loop to stop: it ends
    its batch step, writes a whole checkpoint and raises TrainingStopped, so a stop loses only
    the episodes in flight. A second signal interrupts at once. Inactive outside the main
    thread, where Python cannot catch signals."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: str | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> StopRequests:
        if threading.current_thread() is threading.main_thread():
            self._previous = {number: signal.signal(number, self._ask) for number in self.SIGNALS}
        return self

    def __exit__(self, *exc_info: object) -> None:
        for number, handler in self._previous.items():
            signal.signal(number, handler)

    def _ask(self, number: int, frame: object) -> None:
        if self.received is not None:  # asked twice: stop now
            raise KeyboardInterrupt
        self.received = signal.Signals(number).name
