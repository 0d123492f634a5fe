import math

import pytest
import torch
from torch import nn

from evsmap.errors import EvsmapError, UnknownNameError
from evsmap.measure import SpeedRecord, measure_complexity, measure_speed, roofline_gmacs
from evsmap.measure.speed_backends import make_backend
from evsmap.measure.timing_policy import RoundsPolicy


class TwoInputNet(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.rgb = nn.Conv2d(3, 4, 3, padding=1)
        self.depth = nn.Conv2d(1, 4, 3, padding=1)
        self.head = nn.Conv2d(4, 3, 1)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        return self.head(torch.relu(self.rgb(rgb) + self.depth(depth)))


def inputs() -> tuple[torch.Tensor, torch.Tensor]:
    return torch.rand(1, 3, 8, 12), torch.rand(1, 1, 8, 12)


@pytest.mark.parametrize("backend", ["torch", "onnxruntime"])
def test_record_is_consistent(backend, tmp_path):
    net, x = TwoInputNet().train(), inputs()
    before = torch.get_num_threads()
    onnx = {"input_names": ("rgb", "depth"), "key": "tiny", "cache_dir": tmp_path}
    rec = measure_speed(net, x, backend=make_backend(backend, onnx=onnx),
                        policy=RoundsPolicy(runs=3, warmup=1), threads=1, roofline_size=64)
    assert isinstance(rec, SpeedRecord)
    assert torch.get_num_threads() == before and net.training
    assert (rec.backend, rec.height, rec.width) == (backend, 8, 12)
    assert (rec.runs, rec.warmup, rec.threads) == (3, 1, 1)
    assert len(rec.times_ms) == rec.runs and all(t > 0 for t in rec.times_ms)
    assert rec.ms_median == pytest.approx(sorted(rec.times_ms)[1])
    assert rec.fps_median == pytest.approx(1000 / rec.ms_median)
    assert rec.ms_iqr >= 0 and rec.fps_iqr >= 0
    assert rec.macs == measure_complexity(net, x).flops
    assert rec.achieved_gmacs == pytest.approx(rec.macs / rec.ms_median * 1e3 / 1e9)
    assert rec.roofline_gmacs > 0
    assert rec.roofline_fraction == pytest.approx(rec.achieved_gmacs / rec.roofline_gmacs)
    assert set(rec.versions) == {"python", "torch", "onnxruntime", "numpy", "fvcore"}
    assert rec.cpu
    d = rec.as_dict()
    assert d["times_ms"] == rec.times_ms and d["backend"] == backend
    if backend == "onnxruntime":
        assert [p.suffix for p in tmp_path.iterdir()] == [".onnx"]


def test_iqr_from_quartiles(monkeypatch):
    import evsmap.measure.speed as speed

    monkeypatch.setattr(speed, "_time_calls", lambda *a: [0.004, 0.001, 0.002, 0.003, 0.005])
    rec = measure_speed(nn.Conv2d(1, 1, 1), torch.zeros(1, 1, 4, 4),
                        policy=RoundsPolicy(runs=5, warmup=0), macs=2_000_000, roofline_size=32)
    assert rec.ms_median == pytest.approx(3.0)
    assert rec.ms_iqr == pytest.approx(4.0 - 2.0)
    assert rec.fps_iqr == pytest.approx(1000 / 2.0 - 1000 / 4.0)
    assert rec.achieved_gmacs == pytest.approx(2e6 / 3e-3 / 1e9)
    assert rec.macs == 2_000_000


def test_unknown_backend_lists_valid_ones():
    with pytest.raises(UnknownNameError) as info:
        make_backend("tensorrt")
    assert isinstance(info.value, EvsmapError)
    message = str(info.value)
    assert "tensorrt" in message and "torch" in message and "onnxruntime" in message


@pytest.mark.parametrize("kwargs", [{"runs": 0}, {"warmup": -1}, {"max_rounds": 0}])
def test_bad_counts(kwargs):
    with pytest.raises(ValueError):
        RoundsPolicy(**kwargs)


def test_bad_threads():
    with pytest.raises(ValueError, match="threads"):
        measure_speed(nn.Conv2d(1, 1, 1), torch.zeros(1, 1, 4, 4), threads=0)


def test_roofline_is_finite():
    value = roofline_gmacs(32, repeats=2)
    assert value > 0 and math.isfinite(value)


def test_repeats_until_stable_and_flags_what_never_is(monkeypatch):
    """Rounds repeat until IQR/median meets the threshold; a cell that never does keeps its
    steadiest round and is flagged; a calibration far below the run's best flags contention."""
    import evsmap.measure.contention as contention
    import evsmap.measure.speed as speed

    rounds = iter([[1.0, 2.0, 3.0, 4.0], [1.0, 1.0, 1.01, 1.0], [9.0, 9.0, 9.0, 9.0]])
    monkeypatch.setattr(speed, "_time_calls", lambda *a: next(rounds))
    monkeypatch.setattr(speed, "roofline_gmacs", lambda *a, **k: 100.0)
    monkeypatch.setattr(contention, "calibration_gmacs", lambda: 50.0)
    module = torch.nn.Conv2d(3, 4, 3)
    inputs = torch.zeros(1, 3, 8, 8)
    rec = speed.measure_speed(module, inputs, macs=1, policy=RoundsPolicy(
        runs=4, warmup=0, max_rounds=3, stable_rel_iqr=0.05))
    assert rec.rounds == 2 and rec.stable and rec.ms_median == pytest.approx(1000.0)
    assert rec.flag is None and rec.contention["slowdown"] == 1.0
    rounds = iter([[1.0, 2.0, 3.0, 4.0], [1.0, 1.5, 2.0, 2.5]])
    rec = speed.measure_speed(module, inputs, macs=1, policy=RoundsPolicy(
        runs=4, warmup=0, max_rounds=2, stable_rel_iqr=0.05))
    assert rec.rounds == 2 and rec.stable is False and "unstable" in rec.flag
    assert rec.ms_median == pytest.approx(1750.0)  # the steadier second round is kept
    log = contention.CalibrationLog()
    log.best(200.0)  # the run once calibrated at 200 G MAC/s: 50 now is a 4x slowdown
    rounds = iter([[1.0, 1.0, 1.0, 1.0]])
    rec = speed.measure_speed(module, inputs, policy=RoundsPolicy(runs=4, warmup=0), macs=1,
                              calibration_log=log)
    assert rec.contention["contended"] and "4.00x slower" in rec.flag


def test_calibration_log_keeps_the_best_across_processes(tmp_path):
    from evsmap.measure.contention import CalibrationLog

    path = tmp_path / "cal.json"
    assert CalibrationLog(path).best(30.0) == 30.0
    assert CalibrationLog(path).best(20.0) == 30.0  # a new process reads the file
    assert CalibrationLog(path).best(45.0) == 45.0


def test_a_run_loaded_from_its_start_is_compared_with_the_machine_idle(tmp_path):
    from evsmap.measure.contention import CalibrationLog, machine_key

    machine = tmp_path / "machine.json"
    CalibrationLog(tmp_path / "idle-run.json", machine_path=machine).best(100.0)
    loaded = CalibrationLog(tmp_path / "loaded-run.json", machine_path=machine)
    assert loaded.best(40.0) == 100.0  # the idle run's best, from the machine file
    import json

    assert json.loads(machine.read_text())[machine_key()] == 100.0
