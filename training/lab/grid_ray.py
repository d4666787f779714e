"""Grid cells as Ray tasks (`python -m training grid --backend ray`): each cell's run a process
started by a task that holds `threads` CPUs of the cluster, on a local Ray instance or the
cluster at an address (as terl-rt's evaluation joins one: terl_rt.evaluation.ray_backend).

This module imports Ray (the `ray` extra); the grid command imports it only when asked for.
On a cluster, every node must see the grid's folder and the recipes at the paths the driver
gives (a shared file system), and have this package installed.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Sequence

import ray
from ray.exceptions import RayError, TaskCancelledError

from terl_rt.evaluation.ray_backend import connect
from training.lab.grid import RUN_PROGRAM, STOPPED, Cell, CellStack

FAILED = 1
"""The exit status given to a cell whose task Ray lost (its worker or node died)."""


def run_cell(program: Sequence[str], arguments: Sequence[str], log: str, cwd: str) -> int:
    """Run one cell as a process of this worker, its output appended to `log`; its exit status.
    A cancelled task (KeyboardInterrupt, Ray's way) asks the process to stop with a checkpoint."""
    with open(log, "ab") as output:
        process = subprocess.Popen(
            [sys.executable, *program, *arguments], cwd=cwd, stdin=subprocess.DEVNULL, stdout=output,
            stderr=subprocess.STDOUT, start_new_session=True, env={**os.environ, "OMP_NUM_THREADS": "1"},
        )
        try:
            return process.wait()
        except KeyboardInterrupt:
            process.send_signal(signal.SIGTERM)
            return process.wait()


class RayCells:
    """Cells (or stacks of seeds trained together, one a task) as Ray tasks of `threads` CPUs each (training.lab.grid.CellRunner)."""

    def __init__(self, address: str | None, cpus: int | None = None, threads: int = 1,
                 program: Sequence[str] = RUN_PROGRAM) -> None:
        """Join the cluster at `address` (None: start a local Ray instance of `cpus` CPUs, None:
        this machine's); every cell a task of `threads` CPUs running `program` (python's arguments)."""
        self._started = not ray.is_initialized()
        if self._started:
            connect(address, cpus)
        self.program = list(program)
        self._task = ray.remote(run_cell).options(num_cpus=threads, max_retries=0)

    def start(self, cell: Cell | CellStack) -> ray.ObjectRef:
        cell.log.parent.mkdir(parents=True, exist_ok=True)
        return self._task.remote(self.program, cell.arguments(), str(cell.log.resolve()), os.getcwd())

    def poll(self, handle: ray.ObjectRef) -> int | None:
        if not ray.wait([handle], timeout=0)[0]:
            return None
        try:
            return ray.get(handle)
        except TaskCancelledError:
            return STOPPED
        except RayError:
            return FAILED

    def stop(self, handle: ray.ObjectRef) -> None:
        ray.cancel(handle)

    def close(self) -> None:
        if self._started and ray.is_initialized():
            ray.shutdown()
