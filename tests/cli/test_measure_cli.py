import json

import pytest
import torch
from torch import nn

import evsmap.measure.speed as speed_module
from evsmap.cli.main import main
from evsmap.interfaces import Segmenter
from evsmap.registry import SEGMENTERS

NAME = "tiny-measure-test-net"


class _Net(nn.Module):
    def __init__(self, classes: int) -> None:
        super().__init__()
        self.rgb = nn.Conv2d(3, 4, 3, padding=1)
        self.depth = nn.Conv2d(1, 4, 3, padding=1)
        self.head = nn.Conv2d(4, classes, 1)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        return self.head(torch.sigmoid(self.rgb(rgb) + self.depth(depth)))


class TinySegmenter(Segmenter):
    """A network segmenter with what the measuring commands use: the interface's network
    attributes (no prediction)."""

    input_names = ("rgb", "depth")
    default_size = (6, 10)

    def __init__(self, num_classes: int) -> None:
        self.name = NAME
        self.num_classes = num_classes
        self.class_names = tuple(f"c{i}" for i in range(num_classes))
        self._module = _Net(num_classes).eval()

    @property
    def module(self) -> torch.nn.Module:
        return self._module

    def predict(self, frame, *, k=3):
        raise NotImplementedError("the measuring commands do not predict")

    def example_inputs(self, height: int, width: int) -> tuple[torch.Tensor, ...]:
        return torch.zeros(1, 3, height, width), torch.zeros(1, 1, height, width)


def params(classes: int) -> int:
    return (3 * 4 * 9 + 4) + (1 * 4 * 9 + 4) + (4 * classes + classes)


@pytest.fixture
def tiny_segmenter(monkeypatch, tmp_path):
    def factory(*, num_classes: int = 3) -> TinySegmenter:
        """Tiny two-input test network."""
        return TinySegmenter(num_classes)

    SEGMENTERS.add(NAME, factory)
    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path / "cache"))
    real = speed_module.roofline_gmacs  # a small matmul keeps the test fast
    monkeypatch.setattr(speed_module, "roofline_gmacs", lambda size=0, **kw: real(64, **kw))
    yield NAME
    SEGMENTERS.unregister(NAME)


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_complexity_json(capsys, tiny_segmenter):
    code, out, err = run(capsys, "complexity", tiny_segmenter, "--json")
    assert code == 0 and err == ""
    data = json.loads(out)
    assert {"model", "params", "flops", "conv_macs", "uncounted_ops", "height", "width",
            "num_classes"} <= set(data)
    assert data["model"] == tiny_segmenter and data["num_classes"] == 3
    assert (data["height"], data["width"]) == (6, 10)  # the segmenter's default size
    assert data["params"] == params(3)
    assert data["conv_macs"] == (3 * 4 * 9 + 4 * 9 + 4 * 3) * 60
    assert data["uncounted_ops"]["aten::sigmoid"] == 1

    code, out, _ = run(capsys, "complexity", tiny_segmenter, "--json", "--classes", "7",
                       "--height", "8", "--width", "4")
    data = json.loads(out)
    assert code == 0 and data["num_classes"] == 7 and data["params"] == params(7)
    assert (data["height"], data["width"]) == (8, 4)
    assert data["conv_macs"] == (3 * 4 * 9 + 4 * 9 + 4 * 7) * 32


def test_complexity_text(capsys, tiny_segmenter):
    code, out, _ = run(capsys, "complexity", tiny_segmenter)
    assert code == 0
    lines = out.splitlines()
    assert [line.split()[0] for line in lines] == ["model", "input", "params", "FLOPs", "conv",
                                                   "uncounted"]
    assert f"({params(3)})" in out and "10x6" in out and "aten::sigmoid x1" in out


SPEED_KEYS = {"model", "fps_median", "fps_iqr", "ms_median", "ms_iqr", "backend", "threads",
              "roofline_fraction", "roofline_gmacs", "achieved_gmacs", "height", "width", "runs",
              "versions"}


@pytest.mark.parametrize("backend", ["torch", "onnxruntime"])
def test_speed_json(capsys, tiny_segmenter, tmp_path, backend):
    code, out, err = run(capsys, "speed", tiny_segmenter, "--json", "--backend", backend,
                         "--runs", "2", "--warmup", "0", "--threads", "1", "--height", "8",
                         "--width", "8")
    # stderr holds the one note that the network runs its seeded random initialisation
    assert code == 0 and err.splitlines() == [
        f"evsmap speed: note: {tiny_segmenter} runs its random initialisation (seed 0, no "
        f"--weights); nothing measured here depends on the weights"]
    data = json.loads(out)
    assert (data["weights"], data["random_weights"], data["init_seed"]) == (None, True, 0)
    assert SPEED_KEYS <= set(data)
    assert data["model"] == tiny_segmenter and data["backend"] == backend
    assert (data["runs"], data["threads"], data["height"], data["width"]) == (2, 1, 8, 8)
    assert len(data["times_ms"]) == 2
    assert data["fps_median"] == pytest.approx(1000 / data["ms_median"])
    exported = list((tmp_path / "cache" / "onnx").glob("*.onnx"))
    assert len(exported) == (1 if backend == "onnxruntime" else 0)
    if exported:
        assert exported[0].name.startswith(tiny_segmenter)


def test_speed_text(capsys, tiny_segmenter):
    code, out, _ = run(capsys, "speed", tiny_segmenter, "--runs", "2", "--warmup", "1")
    assert code == 0
    assert [line.split()[0] for line in out.splitlines()] == [
        "model", "fps", "latency", "roofline", "cpu", "versions"]
    assert "10x6" in out and "backend torch" in out


@pytest.mark.parametrize("command", ["complexity", "speed"])
def test_unknown_model_is_one_line(capsys, command):
    code, out, err = run(capsys, command, "feagnet-v9000", "--json")
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"evsmap {command}: error: unknown segmenter 'feagnet-v9000'")


@pytest.mark.parametrize("argv", [["--backend", "tensorrt"], ["--runs", "0"],
                                  ["--threads", "-1"], ["--height", "x"]])
def test_bad_options(capsys, tiny_segmenter, argv):
    with pytest.raises(SystemExit) as info:
        main(["speed", tiny_segmenter, *argv])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_backends_match_measure_module():
    from evsmap.cli.speed_cmd import BACKENDS, COMPILE_MODES
    from evsmap.measure import speed_backends

    assert sorted(BACKENDS) == sorted(speed_backends.BACKENDS)
    assert COMPILE_MODES == speed_backends.COMPILE_MODES


# -- evsmap map -------------------------------------------------------------------------------

def _evsmap(*args: str):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "evsmap", *args], capture_output=True,
                          text=True, timeout=600)


def test_map_synthetic_json_has_the_record_keys(tmp_path):
    import json

    out = tmp_path / "m.ot"
    r = _evsmap("map", "synthetic", "--updater", "multiclass-bayes", "--frames", "2",
                "--resolution", "0.1", "--out", str(out), "--json")
    assert r.returncode == 0, r.stderr
    rec = json.loads(r.stdout)
    for key in ("frames", "update_hz", "wall_hz", "segment_update_hz", "wall_s",
                "map_bytes", "octomap_memory_bytes", "nodes", "leaves"):
        assert key in rec
    # measured memory: the map's arrays and the run's peak RSS, above its start
    assert rec["map_nbytes"] > 0 and rec["peak_scope"] == "run"
    assert rec["peak_rss_bytes"] >= rec["start_rss_bytes"] > 10e6
    assert rec["frames"] == 2 and rec["segmenter"] == "oracle"
    # the front end, per frame: multiclass-bayes runs SSMI's octomap_generator by default
    fe = rec["front_end"]
    assert fe["name"] == "generator" and len(fe["centroids"]) == 2
    assert all(c >= h > 0 for c, h in zip(fe["centroids"], fe["hits"], strict=True))
    # SSMI saves its colour-only form; its octomap_full message carries the semantics
    assert rec["map_bytes_colour"] == rec["map_bytes_published"] < rec["map_bytes_message"]
    from evsmap.environment import describe

    assert rec["machine"] == describe()  # the rates are this machine's: it says which
    assert rec["map_bytes"] == out.stat().st_size
    assert rec["wall_hz"] <= rec["update_hz"]
    assert rec["wall_hz"] == pytest.approx(rec["frames"] / rec["wall_s"])
    assert rec["pipeline"]["enabled"] is True and rec["pipeline"]["update"]["numba"] >= 1
    # the synthetic scene has ground truth: the map is scored against it
    q = rec["quality"]
    assert q["resolution"] == pytest.approx(0.1) and q["occupied"] > 0 and q["matched"] > 0
    assert 0.5 < q["precision"] <= 1.0 and 0.0 < q["recall"] <= 1.0
    assert 0.3 < q["semantic_accuracy"] <= 1.0 and 0.0 < q["map_miou"] <= 1.0


def test_map_prints_the_3d_scores_and_none_without_ground_truth(tum_dir):
    import json

    r = _evsmap("map", "synthetic", "--updater", "orgb", "--frames", "2", "--resolution", "0.1")
    assert r.returncode == 0, r.stderr
    assert "geometry     precision" in r.stdout and "semantics" not in r.stdout.split(
        "geometry")[1]
    r = _evsmap("map", str(tum_dir), "--updater", "orgb", "--frames", "1", "--json")
    assert r.returncode == 0, r.stderr
    assert "quality" not in json.loads(r.stdout)


def test_map_user_errors_are_one_line(tmp_path, tum_dir):
    cases = [
        ("map", "synthetic", "--updater", "nope"),
        ("map", str(tmp_path / "missing"), "--updater", "orgb"),
        ("map", "synthetic", "--updater", "orgb", "--out", str(tmp_path / "m.txt")),
        ("map", str(tum_dir), "--updater", "multiclass-bayes", "--frames", "1"),
        ("map", "synthetic", "--updater", "multiclass-bayes", "-o", "psi=abc"),
        ("map", "synthetic", "--updater", "classic-semantic", "-o", "clamp_min=x"),
        ("map", "synthetic", "--updater", "orgb", "--max-range", "0"),
        ("complexity", "feagnet-v1", "--height", "17", "--width", "31"),
        ("speed", "feagnet-v1", "--height", "17", "--width", "31"),
    ]
    for args in cases:
        r = _evsmap(*args)
        assert r.returncode == 2, (args, r.stderr)
        assert "Traceback" not in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "option psi must be a number, got 'abc'" in _evsmap(*cases[4]).stderr


def test_map_refuses_random_weights_unless_allowed(tmp_path):
    """The one weights policy: a semantic map's classes depend on the weights, so an untrained
    network is refused without --allow-random; with it the map is made from the random
    initialisation of --seed (recorded), twice the same file byte for byte, and a warning says
    so. (An untrained FEAGNet predicts one class almost everywhere whatever the seed, so the
    seeds' weights are compared in tests/segmenters/test_create.py, not their maps.)"""
    base = ("map", "synthetic", "--updater", "multiclass-bayes", "--segmenter", "feagnet-v1",
            "--frames", "2", "--resolution", "0.2")
    r = _evsmap(*base)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.splitlines() == [
        "evsmap map: error: feagnet-v1 has no trained weights: pass --weights FILE (or "
        "--allow-random to run its random initialisation, seed 0: the classes in the map are "
        "noise)"]
    maps = []
    for name in ("a", "b", "c"):
        seed = ("--seed", "3") if name == "c" else ()
        out = tmp_path / f"{name}.ot"
        r = _evsmap(*base, "--allow-random", *seed, "--out", str(out), "--json")
        assert r.returncode == 0, r.stderr
        assert "warning: feagnet-v1 runs with RANDOM weights (seed" in r.stderr
        record = json.loads(r.stdout)
        assert (record["random_weights"], record["init_seed"]) == (True, 3 if seed else 0)
        maps.append(out.read_bytes())
    assert maps[0] == maps[1]


def test_classic_semantic_published_file_is_semantic_slams_color_octree(tmp_path):
    """--file-format published: semantic_slam's file, a ColorOcTree (float log-odds + the top
    class's colour a node) that octomap-python opens, with the node count --json reports; every
    leaf shows a colour of semantic_slam's VOC colour map, an averaged one, or white."""
    import json

    import octomap

    from baselines.semantic_slam import voc_colormap

    out = tmp_path / "c.ot"
    r = _evsmap("map", "synthetic", "--updater", "classic-semantic", "--frames", "2",
                "--resolution", "0.1", "--out", str(out), "--file-format", "published",
                "--json")
    assert r.returncode == 0, r.stderr
    rec = json.loads(r.stdout)
    assert rec["file_format"] == "published" and rec["map_bytes"] == out.stat().st_size
    assert rec["map_bytes_published"] == rec["map_bytes"] < rec["map_bytes_full"]
    tree = octomap.ColorOcTree.read(str(out).encode())
    assert tree.size() == rec["nodes"] and tree.getNumLeafNodes() == rec["leaves"]
    # 8 bytes a node (float, rgb, child mask) after the header
    assert rec["map_bytes"] - 8 * rec["nodes"] < 200
    colours = {tuple(c) for c in voc_colormap(40).tolist()}
    seen = {tuple(int(v) for v in leaf.getColor()) for leaf in tree.begin_leafs()}
    assert len(seen & colours) >= 3 and (255, 255, 255) in seen
    # full (the default) reloads into evsmap; on the direct front end multiclass-bayes writes
    # the same file either way; on SSMI's generator it publishes SSMI's writeData (36 B a
    # node: value, the semantic colour and the padded SemanticsLogOdds struct)
    r = _evsmap("map", "synthetic", "--updater", "multiclass-bayes", "-o", "front_end=direct",
                "--frames", "1", "--resolution", "0.1", "--json")
    rec = json.loads(r.stdout)
    assert rec["file_format"] == "full" and rec["map_bytes_full"] == rec["map_bytes_published"]
    r = _evsmap("map", "synthetic", "--updater", "multiclass-bayes", "--frames", "1",
                "--resolution", "0.1", "--json")
    rec = json.loads(r.stdout)
    assert rec["map_bytes_published"] - 36 * rec["nodes"] < 200
