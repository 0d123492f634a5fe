"""``--device``: its spellings, the one-line refusals where this machine or build lacks the GPU
(simulated where this machine has none), the pass timer, the warm-up until the speed settles,
and the GPU facts read from ``nvidia-smi``."""

from __future__ import annotations

import os
import time

import pytest
import torch

from evsmap import devices
from evsmap.devices import (
    DeviceUnavailableError,
    PassTimer,
    device_name,
    require_device,
    settle,
)
from evsmap.environment import collect_gpu, gpu_clocks
from evsmap.errors import EvsmapError, UnknownNameError


@pytest.mark.parametrize("text, canonical", [
    ("cpu", "cpu"), ("CPU", "cpu"), ("cuda", "cuda:0"), ("cuda:1", "cuda:1"),
    (" cuda:02 ", "cuda:2"),
])
def test_spellings(text, canonical):
    assert device_name(text) == canonical


@pytest.mark.parametrize("text", ["gpu", "cpu:0", "cuda:-1", "cuda:x", "", "mps", "cuda:0:1"])
def test_a_misspelt_device_names_the_known_ones(text):
    with pytest.raises(UnknownNameError, match="known: cpu"):
        device_name(text)


def test_the_cpu_is_always_there():
    assert require_device("cpu") == torch.device("cpu")


def test_cuda_refusals_say_why(monkeypatch):
    monkeypatch.setattr(torch.version, "cuda", None)
    with pytest.raises(DeviceUnavailableError, match="CPU build without CUDA"):
        require_device("cuda")
    monkeypatch.setattr(torch.version, "cuda", "12.8")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(DeviceUnavailableError, match="sees no GPU"):
        require_device("cuda:0")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    with pytest.raises(DeviceUnavailableError, match=r"only 2 GPUs visible \(cuda:0 to cuda:1\)"):
        require_device("cuda:2")
    assert require_device("cuda:1") == torch.device("cuda:1")
    assert issubclass(DeviceUnavailableError, EvsmapError)  # one line, exit 2 on the CLI


def test_the_cpu_timer_is_the_host_clock():
    timer = PassTimer("cpu")
    assert timer.kind == "host clock"
    assert 0.02 <= timer(lambda: time.sleep(0.02)) < 1.0


class FakeClock:
    """A clock each timed pass moves by the pass's time (so ``settle``'s limits are exact)."""

    def __init__(self, times):
        self.now, self.times = 0.0, iter(times)

    def clock(self):
        return self.now

    def timer(self, call):
        call()
        t = next(self.times)
        self.now += t
        return t


def test_settle_runs_until_two_windows_agree_and_the_minimum_time_passed():
    # ramping down for 3 windows of 4 passes, then steady: settles in window 5 (the first
    # steady one after the minimum time), not earlier
    ramp = [0.5] * 4 + [0.4] * 4 + [0.3] * 4 + [0.2] * 4 + [0.2] * 4 + [0.2] * 40
    fake = FakeClock(ramp)
    calls = []
    out = settle(lambda: calls.append(1), fake.timer, window=4, tolerance=0.02, min_s=1.0,
                 max_s=100.0, clock=fake.clock)
    assert out.settled and out.passes == 20 == len(calls)
    assert out.median_s == pytest.approx(0.2) and out.seconds == pytest.approx(6.4)
    assert out.as_dict()["median_ms"] == pytest.approx(200.0)


def test_settle_stops_at_its_limit_when_the_speed_keeps_drifting():
    fake = FakeClock([0.1 * 0.9 ** i for i in range(1000)])
    out = settle(lambda: None, fake.timer, window=5, tolerance=0.01, min_s=0.0, max_s=0.5,
                 clock=fake.clock)
    assert not out.settled and out.seconds >= 0.5 and out.passes % 5 == 0


def test_settle_refuses_bad_settings():
    with pytest.raises(ValueError):
        settle(lambda: None, PassTimer(), window=1)
    with pytest.raises(ValueError):
        settle(lambda: None, PassTimer(), min_s=2.0, max_s=1.0)


def test_no_gpu_facts_for_the_cpu():
    assert collect_gpu("cpu") == {}


def _fake_smi(tmp_path, monkeypatch, body):
    script = tmp_path / "nvidia-smi"
    script.write_text("#!/bin/sh\n" + body)
    script.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ['PATH']}")


def test_gpu_clocks_come_from_nvidia_smi(tmp_path, monkeypatch):
    _fake_smi(tmp_path, monkeypatch,
              'echo "570.86.15, 1980, 1980, 2619, 2619, 700.00, P0, 41"\n')
    facts = gpu_clocks(0)
    assert facts == {"driver_version": "570.86.15", "clocks_sm": "1980",
                     "clocks_max_sm": "1980", "clocks_mem": "2619", "clocks_max_mem": "2619",
                     "power_limit": "700.00", "pstate": "P0", "temperature_gpu": "41"}


def test_gpu_clocks_say_why_they_are_missing(tmp_path, monkeypatch):
    _fake_smi(tmp_path, monkeypatch, "exit 9\n")
    assert gpu_clocks(0)["nvidia_smi"].startswith("failed")
    _fake_smi(tmp_path, monkeypatch, 'echo "just, three, fields"\n')
    assert "unexpected output" in gpu_clocks(0)["nvidia_smi"]
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    assert gpu_clocks(0) == {"nvidia_smi": "not found"}


def test_the_parser_side_imports_no_torch():
    import subprocess
    import sys

    code = ("import sys; import evsmap.devices as d; d.device_name('cuda:1'); "
            "sys.exit(1 if 'torch' in sys.modules else 0)")
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
    assert devices.DEVICES_HELP.startswith("cpu")
