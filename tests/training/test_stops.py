"""A stopped training run (Ctrl-C, `kill PID`) keeps a whole checkpoint and goes on from it."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from training.__main__ import main
from training.checkpoint import read_counters
from training.config import Config
from training.stops import StopRequests
from training.seed_state import METRICS_FILE

ROOT = Path(__file__).resolve().parents[2]


def test_a_first_signal_only_asks_to_stop_and_a_second_interrupts():
    previous = signal.getsignal(signal.SIGINT)
    with StopRequests() as stops:
        signal.raise_signal(signal.SIGINT)
        assert stops.received == "SIGINT"
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGTERM)
    assert signal.getsignal(signal.SIGINT) is previous


def test_sigterm_ends_the_batch_step_writes_a_checkpoint_and_the_run_goes_on(tmp_path):
    config_file, out = tmp_path / "long.json", tmp_path / "run"
    Config.of(  # a tiny network; no checkpoint or snapshot falls due before the stop
        model="terl", hidden=16, layers=1, heads=2, total_steps=10_000_000, num_envs=4, batch_size=32,
        buffer_size=5_000, learning_starts=80, snapshot_frequency=0, log_frequency=160,
        checkpoint_frequency=10_000_000,
    ).to_file(config_file)
    command = [sys.executable, "-m", "training", "train", "--config", str(config_file), "--out", str(out), "--quiet"]
    run = subprocess.Popen(command, cwd=ROOT, stderr=subprocess.PIPE, text=True,
                           env={**os.environ, "OMP_NUM_THREADS": "1"})
    deadline = time.monotonic() + 120
    while not (out / METRICS_FILE).is_file() and time.monotonic() < deadline:  # the first log: updates under way
        time.sleep(0.2)
    run.send_signal(signal.SIGTERM)
    _, stderr = run.communicate(timeout=120)

    assert run.returncode == 130, stderr
    stopped_at = int(re.search(r"stopped by SIGTERM at environment step ([\d,]+)", stderr).group(1).replace(",", ""))
    assert read_counters(out).env_step == stopped_at > 0  # no checkpoint was due: the stop wrote it
    assert main(["train", "--resume", str(out), "--total-steps", str(stopped_at + 40), "--quiet"]) == 0
    assert read_counters(out).env_step == stopped_at + 40
