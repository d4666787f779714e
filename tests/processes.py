"""Processes seen through /proc (Linux): children, descendants, liveness, command lines."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path


def _parents() -> dict[int, int]:
    """pid -> parent pid of every live (not zombie) process."""
    parents = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as handle:
                fields = handle.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":
            parents[int(entry)] = int(fields[1])
    return parents


def children(pid: int) -> set[int]:
    """Process ids whose parent is `pid`."""
    return {child for child, parent in _parents().items() if parent == pid}


def descendants(pid: int) -> set[int]:
    """Process ids below `pid`: its children, their children and so on."""
    below: dict[int, list[int]] = {}
    for child, parent in _parents().items():
        below.setdefault(parent, []).append(child)
    found, todo = set(), [pid]
    while todo:
        for child in below.get(todo.pop(), []):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as handle:
            return handle.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def cmdline(pid: int) -> str:
    """The command line of `pid`, arguments joined by spaces ("" once it has gone)."""
    try:
        with open(f"/proc/{pid}/cmdline") as handle:
            return handle.read().replace("\0", " ").strip()
    except OSError:
        return ""


def start_eval(policy_path: Path, log: Path, *options: str) -> subprocess.Popen:
    """`terl-rt eval` of 6 episodes of small-11 (400 steps) on 2 workers, logged to `log`,
    in its own process group (what a terminal's Ctrl-C reaches); `options` are added."""
    command = [
        sys.executable, "-c", "from terl_rt.cli.main import cli; cli()", "eval", "--policy", str(policy_path),
        "--scenario", "small-11", "--episodes", "6", "--max-steps", "400", "--workers", "2", "--log", str(log),
        *options,
    ]
    return subprocess.Popen(command, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def wait_for_log(process: subprocess.Popen, log: Path, size: int = 150_000, limit_s: float = 60.0) -> None:
    """Wait until `log` has grown past `size` bytes while `process` runs."""
    deadline = time.monotonic() + limit_s
    while (not log.exists() or log.stat().st_size < size) and time.monotonic() < deadline:
        assert process.poll() is None, "the evaluation ended before it could be stopped"
        time.sleep(0.05)


def assert_all_end(pids: set[int], limit_s: float = 5.0) -> None:
    """Every process of `pids` ends within `limit_s`."""
    deadline = time.monotonic() + limit_s
    while any(alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    survivors = {pid: cmdline(pid)[:200] for pid in pids if alive(pid)}
    assert not survivors, f"outlived the evaluation: {survivors}"
