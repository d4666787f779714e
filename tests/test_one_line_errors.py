"""Every user error is one `Error:` line and exit status 2, never a traceback (issue 14, item 5)."""

from __future__ import annotations

import builtins
import errno

import pytest
from one_line import invoke

import terl_rt.logs.writer
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.resimulate import verify


def assert_one_error(result, *words):
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith("Error: ") and result.stderr.count("\n") == 1, result.stderr
    assert "Traceback" not in result.output and result.exception is None or isinstance(result.exception, SystemExit)
    for word in words:
        assert word in result.stderr, result.stderr


CASES = {
    "negative seed": (("eval", "--seed", "-1"), "--seed"),
    "huge seed": (("eval", "--seed", str(10**30)), "--seed"),
    "tiny fps": (("render", "{log}", "-o", "{folder}/x.gif", "--fps", "1e-9"), "--fps"),
    "nan fps": (("render", "{log}", "-o", "{folder}/x.gif", "--fps", "nan"), "fps"),
    "huge size": (("render", "{log}", "-o", "{folder}/x.png", "--size", "1000000000"), "--size"),
    "huge threads": (("eval", "--policy", "{policy}", "--threads", "1000000000"), "--threads"),
    "huge workers": (("eval", "--policy", "{policy}", "--workers", "1000000"), "--workers"),
    "huge episodes": (("eval", "--policy", "{policy}", "--episodes", str(10**12)), "--episodes"),
    "huge max steps": (("eval", "--policy", "{policy}", "--max-steps", str(10**12)), "--max-steps"),
    "huge bench envs": (("bench", "sim", "--envs", str(10**9)), "--envs"),
    "unknown option": (("eval", "--frobnicate"), "--frobnicate"),
    "device as policy": (("eval", "--policy", "/dev/zero"), "not a regular file"),
    "device as info policy": (("info", "/dev/zero"), "not a regular file"),
    "device as scenario file": (("eval", "--policy", "{policy}", "--scenario-file", "/dev/zero"), "not a regular file"),
    "device as log": (("replay", "/dev/zero"), "not a regular file"),
    "device as render input": (("render", "/dev/zero", "-o", "{folder}/y.png"), "not a regular file"),
    "device as log output": (("eval", "--policy", "{policy}", "--log", "/dev/zero", "--force"), "not a regular file"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_one_error_line(logged_eval, case):
    args, word = CASES[case]
    result = invoke(*(arg.format(**logged_eval) for arg in args))
    assert_one_error(result, word)


class _FullDisk:
    """A file that takes `room` bytes and then fails every write with ENOSPC."""

    def __init__(self, handle, room: int):
        self._handle, self._room = handle, room

    def write(self, data) -> int:
        if len(data) > self._room:
            self._handle.write(bytes(data[: self._room]))
            self._handle.flush()
            self._room = 0
            raise OSError(errno.ENOSPC, "No space left on device")
        self._room -= len(data)
        return self._handle.write(data)

    def __getattr__(self, name):
        return getattr(self._handle, name)


def test_a_full_disk_while_logging_is_one_line_and_keeps_the_complete_steps(logged_eval, tmp_path, monkeypatch):
    def full_open(path, mode="r", *args, **kwargs):
        return _FullDisk(builtins.open(path, mode, *args, **kwargs), 60_000)

    monkeypatch.setattr(terl_rt.logs.writer, "open", full_open, raising=False)
    log = tmp_path / "full.mcap"
    result = invoke("eval", "--policy", logged_eval["policy"], "--scenario", "small-11", "--episodes", "2",
                    "--max-steps", "100", "--log", log)
    # The progress bar's label may precede it on stderr; the error itself is one line.
    assert result.exit_code == 2, result.output
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error:")]
    assert len(errors) == 1 and result.stderr.endswith(errors[0] + "\n") and "No space left on device" in errors[0]
    assert errors[0] == f"Error: {log}: No space left on device"  # the user's path, not the temporary file
    assert "Traceback" not in result.output
    reader = EpisodeLogReader(log)
    assert reader.truncated and reader.episodes[0].steps > 0
    assert verify(log, 0).ok
