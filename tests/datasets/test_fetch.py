"""``evsmap datasets fetch`` against a local HTTP server (127.0.0.1 only) serving tiny archives in
the official layouts: full fetches, resume, checksum / size / 404 / missing-member errors, the size
prompt, the listing; and the catalogue's expected values against the real samples."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import io
import json
import signal
import subprocess
import sys
import tarfile
import threading
import time
import zipfile
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import h5py
import numpy as np
import pytest
from datasets_fixtures import nyu_arrays, nyu_map_class, write_nyu_source
from PIL import Image

from evsmap import download, fetch, samples
from evsmap.cli.main import main
from evsmap.datasets import nyuv2
from evsmap.samples import SAMPLES, Source, array_digest
from evsmap.testing import require_sample


# -- a small HTTP server ------------------------------------------------------------------------
class _Answered(Exception):
    """The request was answered (a redirect)."""


class FileServer:
    """Files by URL path; per path: cut the connection after N bytes the first time, serve wrong
    bytes, refuse HEAD. Every request is recorded (method, path, Range header)."""

    def __init__(self) -> None:
        self.files: dict[str, bytes] = {}
        self.cut_once: dict[str, int] = {}
        self.interrupt_at: dict[str, int] = {}  # path -> bytes sent before Ctrl-C reaches us
        self.wrong: set[str] = set()
        self.redirects: dict[str, str] = {}
        self.no_head = False
        self.requests: list[tuple[str, str, str | None]] = []
        self.lock = threading.Lock()
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args) -> None:  # quiet
                pass

            def _lookup(self) -> bytes | None:
                with server.lock:
                    server.requests.append((self.command, self.path, self.headers.get("Range")))
                    data = server.files.get(self.path)
                    moved = server.redirects.get(self.path)
                if moved is not None:
                    self.send_response(302)
                    self.send_header("Location", moved)
                    self.send_header("Content-Length", "0")
                    self.end_headers()
                    raise _Answered
                if data is not None and self.path in server.wrong:
                    data = bytes(b ^ 0x5A for b in data)
                return data

            def do_HEAD(self) -> None:
                try:
                    data = self._lookup()
                except _Answered:
                    return
                if server.no_head:
                    self.send_error(405)
                elif data is None:
                    self.send_error(404)
                else:
                    self.send_response(200)
                    self.send_header("Content-Length", str(len(data)))
                    self.send_header("Accept-Ranges", "bytes")
                    self.end_headers()

            def do_GET(self) -> None:
                try:
                    data = self._lookup()
                except _Answered:
                    return
                if data is None:
                    self.send_error(404)
                    return
                start = 0
                rng = self.headers.get("Range")
                if rng:
                    start = int(rng.removeprefix("bytes=").split("-")[0])
                    if start >= len(data):
                        self.send_response(416)
                        self.send_header("Content-Range", f"bytes */{len(data)}")
                        self.send_header("Content-Length", "0")
                        self.end_headers()
                        return
                    self.send_response(206)
                    self.send_header("Content-Range",
                                     f"bytes {start}-{len(data) - 1}/{len(data)}")
                else:
                    self.send_response(200)
                body = data[start:]
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                with server.lock:
                    cut = server.cut_once.pop(self.path, None)
                if cut is not None:
                    self.wfile.write(body[:cut])
                    self.wfile.flush()
                    self.close_connection = True
                    return
                with server.lock:
                    at = server.interrupt_at.pop(self.path, None)
                if at is not None:
                    # Ctrl-C in the middle of the transfer: the signal reaches the client (this
                    # process's main thread) while the rest is still on its way
                    self.wfile.write(body[:at])
                    self.wfile.flush()
                    time.sleep(0.3)  # the client is now waiting for the rest
                    signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)
                    time.sleep(0.5)
                    with contextlib.suppress(OSError):
                        self.wfile.write(body[at:])
                    return
                self.wfile.write(body)

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}"
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def gets(self, path: str) -> list[str | None]:
        """The Range headers of the GET requests for ``path``."""
        return [r for m, p, r in self.requests if m == "GET" and p == path]

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
        self.thread.join(timeout=5)


@pytest.fixture
def server(request, monkeypatch):
    srv = FileServer()
    request.addfinalizer(srv.close)
    monkeypatch.setenv(download.MIRROR_ENV, srv.url + "/mirror")
    monkeypatch.setattr(download, "RETRY_DELAY", 0.0)
    monkeypatch.setattr(download, "TIMEOUT", 10.0)
    return srv


def run(capsys, *argv):
    try:
        code = main(list(argv))
    except SystemExit as exc:  # argparse errors
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def use(monkeypatch, name: str, **changes) -> samples.Sample:
    """Replace catalogue entry ``name`` for this test."""
    variant = dataclasses.replace(SAMPLES[name], **changes)
    monkeypatch.setitem(SAMPLES, name, variant)
    return variant


def fetch_cli(capsys, tmp_path, name, *extra):
    return run(capsys, "datasets", "fetch", name, "--out", str(tmp_path / "root"),
               "--cache-dir", str(tmp_path / "cache"), *extra)


def png_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG")
    return buf.getvalue()


def leftovers(tmp_path: Path) -> list[str]:
    """Everything under the output root and the download cache."""
    return sorted(str(p.relative_to(tmp_path)) for base in ("root", "cache")
                  if (tmp_path / base).exists() for p in (tmp_path / base).rglob("*"))


# -- the bag: a single verbatim file ------------------------------------------------------------
BAG = bytes(np.random.default_rng(0).integers(0, 256, 300_000, dtype=np.uint8))


@pytest.fixture
def bag(server, monkeypatch):
    server.files["/mirror/test.bag"] = BAG
    src = dataclasses.replace(SAMPLES["lidar-odometry-bag"].sources[0], size=len(BAG),
                              sha256=sha(BAG))
    return use(monkeypatch, "lidar-odometry-bag", sources=(src,),
               expected={"lidar_odometry.bag": sha(BAG)})


def test_fetch_bag_manifest_and_existing_output(capsys, tmp_path, server, bag):
    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag")
    assert code == 0, err
    assert err == ""
    assert f"downloading {server.url}/mirror/test.bag (300.0 kB)" in out
    assert out.splitlines()[-1].startswith(
        f"fetched lidar-odometry-bag into {tmp_path / 'root' / 'ros' / 'lidar_odometry.bag'} "
        "(1 file, 300.0 kB, 1 verified")
    target = tmp_path / "root" / "ros" / "lidar_odometry.bag"
    assert target.read_bytes() == BAG
    manifest = json.loads((target.parent / "lidar_odometry.bag.evsmap-sample.json").read_text())
    assert manifest["format"] == "evsmap-sample" and manifest["sample"] == "lidar-odometry-bag"
    assert manifest["source"] == f"{server.url}/mirror/test.bag"
    assert manifest["archives"] == [{"url": f"{server.url}/mirror/test.bag", "file": "test.bag",
                                     "size": len(BAG), "sha256": sha(BAG)}]
    assert manifest["files"] == [{"path": "lidar_odometry.bag", "size": len(BAG),
                                  "sha256": sha(BAG), "check": "sha256"}]
    assert manifest["evsmap_version"] and manifest["date"].endswith("+00:00")
    assert "sha256" in manifest["checks"]
    # nothing else: no staging folder, the archive deleted from the cache
    assert leftovers(tmp_path) == ["root/ros", "root/ros/lidar_odometry.bag",
                                   "root/ros/lidar_odometry.bag.evsmap-sample.json"]

    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag")
    assert code == 2 and out == ""
    assert err == (f"evsmap datasets: error: --out {target}: exists (pass --overwrite to "
                   "replace it)\n")
    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag", "--overwrite",
                               "--keep-archive")
    assert code == 0, err
    assert (tmp_path / "cache" / "test.bag").read_bytes() == BAG  # kept
    # an archive in the cache is used again without downloading
    requests = len(server.requests)
    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag", "--overwrite")
    assert code == 0, err
    assert "downloaded earlier" in out and len(server.requests) == requests
    assert not (tmp_path / "cache" / "test.bag").exists()


def test_interrupted_download_resumes_on_the_next_call(capsys, tmp_path, server, bag):
    server.cut_once["/mirror/test.bag"] = 100_000
    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag", "--retries", "0")
    assert code == 2 and err.count("\n") == 1
    part = tmp_path / "cache" / "test.bag.part"
    assert err == (f"evsmap datasets: error: {server.url}/mirror/test.bag: connection lost after "
                   f"100000 of 300000 bytes (connection closed early); run the command again "
                   f"to resume from {part}\n")
    assert part.stat().st_size == 100_000
    assert not (tmp_path / "root").exists()

    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag")
    assert code == 0, err
    assert server.gets("/mirror/test.bag") == [None, "bytes=100000-"]
    assert (tmp_path / "root" / "ros" / "lidar_odometry.bag").read_bytes() == BAG
    assert not part.exists()


def test_a_broken_transfer_resumes_within_the_call(tmp_path, server, bag):
    server.cut_once["/mirror/test.bag"] = 12_345
    manifest = fetch.fetch_sample("lidar-odometry-bag", tmp_path / "root",
                                  cache_dir=tmp_path / "cache", retries=2)
    assert server.gets("/mirror/test.bag") == [None, "bytes=12345-"]
    assert manifest["files"][0]["sha256"] == sha(BAG)
    assert (tmp_path / "root" / "ros" / "lidar_odometry.bag").read_bytes() == BAG


def test_redirects_keep_head_and_range(tmp_path, server, bag):
    server.files["/files/test.bag"] = server.files.pop("/mirror/test.bag")
    server.redirects["/mirror/test.bag"] = "/files/test.bag"
    server.cut_once["/files/test.bag"] = 50_000
    fetch.fetch_sample("lidar-odometry-bag", tmp_path / "root", cache_dir=tmp_path / "cache",
                       retries=1)
    assert [(m, p, r) for m, p, r in server.requests] == [
        ("HEAD", "/mirror/test.bag", None), ("HEAD", "/files/test.bag", None),
        ("GET", "/mirror/test.bag", None), ("GET", "/files/test.bag", None),
        ("GET", "/mirror/test.bag", "bytes=50000-"), ("GET", "/files/test.bag", "bytes=50000-")]
    assert (tmp_path / "root" / "ros" / "lidar_odometry.bag").read_bytes() == BAG


def test_a_complete_part_file_is_finished_without_downloading(tmp_path, server, bag,
                                                               monkeypatch):
    # size unknown (not catalogued, no HEAD): the server's 416 says the .part is complete
    use(monkeypatch, "lidar-odometry-bag",
        sources=(dataclasses.replace(bag.sources[0], size=None),))
    server.no_head = True
    (tmp_path / "cache").mkdir()
    (tmp_path / "cache" / "test.bag.part").write_bytes(BAG)
    fetch.fetch_sample("lidar-odometry-bag", tmp_path / "root", cache_dir=tmp_path / "cache")
    assert server.gets("/mirror/test.bag") == [f"bytes={len(BAG)}-"]
    assert (tmp_path / "root" / "ros" / "lidar_odometry.bag").read_bytes() == BAG


def test_wrong_checksum_deletes_the_download(capsys, tmp_path, server, bag):
    server.wrong.add("/mirror/test.bag")
    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag")
    assert code == 2 and err.count("\n") == 1
    wrong = sha(bytes(b ^ 0x5A for b in BAG))
    assert err == (f"evsmap datasets: error: {server.url}/mirror/test.bag: sha256 {wrong} is not "
                   f"the expected {sha(BAG)}; the download was deleted\n")
    assert leftovers(tmp_path) == []  # no output, no .part, no archive


def test_wrong_size_is_refused_before_downloading(capsys, tmp_path, server, bag, monkeypatch):
    src = dataclasses.replace(bag.sources[0], size=len(BAG) + 1)
    use(monkeypatch, "lidar-odometry-bag", sources=(src,))
    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag")
    assert code == 2 and out == ""
    assert err == (f"evsmap datasets: error: {server.url}/mirror/test.bag: the server reports "
                   f"300000 bytes, expected 300001 (not the catalogued file)\n")
    assert server.gets("/mirror/test.bag") == [] and leftovers(tmp_path) == []


def test_404_writes_nothing(capsys, tmp_path, server, bag):
    del server.files["/mirror/test.bag"]
    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag")
    assert code == 2 and out == ""
    assert err == f"evsmap datasets: error: {server.url}/mirror/test.bag: HTTP 404 Not Found\n"
    assert leftovers(tmp_path) == []
    # a server that refuses HEAD: the GET gets the 404
    server.no_head = True
    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag")
    assert code == 2 and "/mirror/test.bag: HTTP 404" in err and err.count("\n") == 1
    assert leftovers(tmp_path) == []


def test_a_cached_archive_that_fails_its_checksum_is_downloaded_anew(capsys, tmp_path, server,
                                                                      bag):
    (tmp_path / "cache").mkdir()
    (tmp_path / "cache" / "test.bag").write_bytes(bytes(len(BAG)))  # right size, wrong bytes
    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag", "--keep-archive")
    assert code == 0 and err == ""
    assert server.gets("/mirror/test.bag") == [None]
    assert (tmp_path / "cache" / "test.bag").read_bytes() == BAG
    assert leftovers(tmp_path)[0] == "cache/test.bag"  # no temporary file left by pooch
    assert len(leftovers(tmp_path)) == 4


def test_a_mirror_that_is_not_http_is_one_line(capsys, tmp_path, bag, monkeypatch):
    monkeypatch.setenv(download.MIRROR_ENV, f"file://{tmp_path}")
    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag")
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"evsmap datasets: error: file://{tmp_path}/test.bag: not an HTTP(S) "
                          "URL (")
    assert leftovers(tmp_path) == []


def test_connection_refused_is_one_line(capsys, tmp_path, bag, monkeypatch):
    with ThreadingHTTPServer(("127.0.0.1", 0), BaseHTTPRequestHandler) as closed:
        port = closed.server_address[1]  # bound, then closed: nothing listens there
    monkeypatch.setenv(download.MIRROR_ENV, f"http://127.0.0.1:{port}")
    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag")
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"evsmap datasets: error: http://127.0.0.1:{port}/test.bag: cannot "
                          "connect (")
    assert leftovers(tmp_path) == []


# -- TUM RGB-D: a tiny rgbd_dataset_freiburg1_xyz.tgz -------------------------------------------
def tum_archive(*, drop: str | None = None) -> tuple[bytes, dict[str, bytes]]:
    """A .tgz in the official layout (6 frames) and the files a 4-frame sample holds."""
    top = "rgbd_dataset_freiburg1_xyz"
    rng = np.random.default_rng(1)
    rgb_t = [1305031102.175304 + 0.033 * i for i in range(6)]
    depth_t = [1305031102.160407 + 0.033 * i for i in range(6)]
    members: dict[str, bytes] = {}
    for t in rgb_t:
        members[f"rgb/{t:.6f}.png"] = png_bytes(rng.integers(0, 256, (6, 8, 3), dtype=np.uint8))
    for t in depth_t:
        members[f"depth/{t:.6f}.png"] = png_bytes(
            rng.integers(0, 60000, (6, 8), dtype=np.uint16))
    head = "# color images\n# file: 'rgbd_dataset_freiburg1_xyz.bag'\n# timestamp filename\n"
    members["rgb.txt"] = (head + "".join(f"{t:.6f} rgb/{t:.6f}.png\n" for t in rgb_t)).encode()
    dhead = "# depth maps\n# file: 'rgbd_dataset_freiburg1_xyz.bag'\n# timestamp filename\n"
    members["depth.txt"] = (dhead + "".join(f"{t:.6f} depth/{t:.6f}.png\n"
                                            for t in depth_t)).encode()
    members["groundtruth.txt"] = b"# ground truth trajectory\n" + b"".join(
        f"{1305031098.6659 + 0.01 * i:.4f} 1.3563 0.6305 1.6380 0.6132 0.5962 -0.3311 "
        f"-0.3986\n".encode() for i in range(500))
    members["accelerometer.txt"] = b"# accelerometer data\n1305031098.6 0.1 9.8 0.2\n"
    expected = {
        "rgb.txt": (head + "".join(f"{t:.6f} rgb/{t:.6f}.png\n" for t in rgb_t[:4]))
        .rstrip("\n").encode(),
        "depth.txt": (dhead + "".join(f"{t:.6f} depth/{t:.6f}.png\n" for t in depth_t[:4]))
        .rstrip("\n").encode(),
        "groundtruth.txt": members["groundtruth.txt"],
        **{f"rgb/{t:.6f}.png": members[f"rgb/{t:.6f}.png"] for t in rgb_t[:4]},
        **{f"depth/{t:.6f}.png": members[f"depth/{t:.6f}.png"] for t in depth_t[:4]},
    }
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tf:
        # images first, as in a tree walk that puts the folders before the lists
        for name in sorted(members, key=lambda n: (not n.startswith(("rgb/", "depth/")), n),
                           reverse=True):
            if name == drop:
                continue
            info = tarfile.TarInfo(f"{top}/{name}")
            info.size = len(members[name])
            tf.addfile(info, io.BytesIO(members[name]))
    return buf.getvalue(), expected


@pytest.fixture
def tum(server, monkeypatch):
    data, expected = tum_archive()
    server.files["/mirror/rgbd_dataset_freiburg1_xyz.tgz"] = data
    use(monkeypatch, "tum-fr1-xyz",
        options={"sequence": "rgbd_dataset_freiburg1_xyz", "frames": 4},
        expected={k: sha(v) for k, v in expected.items()})
    return data, expected


def test_fetch_tum(capsys, tmp_path, server, tum):
    data, expected = tum
    code, out, err = fetch_cli(capsys, tmp_path, "tum-fr1-xyz")
    assert code == 0, err
    folder = tmp_path / "root" / "tum_fr1_xyz"
    files = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())
    assert files == sorted([*expected, "evsmap-sample.json"])
    for rel, content in expected.items():
        assert (folder / rel).read_bytes() == content, rel
    manifest = json.loads((folder / "evsmap-sample.json").read_text())
    assert manifest["archives"][0]["sha256"] == sha(data)
    assert manifest["archives"][0]["size"] == len(data)
    assert manifest["options"] == {"sequence": "rgbd_dataset_freiburg1_xyz", "frames": 4}
    assert {f["path"]: f["sha256"] for f in manifest["files"]} == \
        {k: sha(v) for k, v in expected.items()}
    assert {f["check"] for f in manifest["files"]} == {"sha256"}
    # the folder reads as a TUM sequence
    from evsmap.registry import READERS

    seq = READERS.create("tum", path=str(folder))
    assert len(seq) == 4  # 4 depth images, each with an RGB image and a pose
    assert leftovers(tmp_path)[:1] == ["root/tum_fr1_xyz"]


def test_size_prompt_needs_yes(capsys, tmp_path, server, tum, monkeypatch):
    monkeypatch.setattr(fetch, "CONFIRM_BYTES", 1000)
    size = download.format_size(len(tum[0]))
    code, out, err = fetch_cli(capsys, tmp_path, "tum-fr1-xyz")
    assert code == 2 and out == ""
    assert err == (f"evsmap datasets: error: {server.url}/mirror/rgbd_dataset_freiburg1_xyz.tgz: "
                   f"{size} to download; pass --yes to go on\n")
    assert leftovers(tmp_path) == [] and server.gets("/mirror/rgbd_dataset_freiburg1_xyz.tgz") \
        == []
    # a large file whose size the server does not tell: asked as well
    monkeypatch.setattr(fetch, "CONFIRM_BYTES", 10**12)
    use(monkeypatch, "tum-fr1-xyz", sources=(dataclasses.replace(
        SAMPLES["tum-fr1-xyz"].sources[0], large=True),))
    server.no_head = True
    code, out, err = fetch_cli(capsys, tmp_path, "tum-fr1-xyz")
    assert code == 2 and err.endswith("a large download of unknown size; pass --yes to go on\n")
    # an interactive "n" stops too, a "y" goes on
    answers = iter([False, True])
    with pytest.raises(download.FetchError, match="not downloaded"):
        fetch.fetch_sample("tum-fr1-xyz", tmp_path / "root", cache_dir=tmp_path / "cache",
                           confirm=lambda message: next(answers))
    fetch.fetch_sample("tum-fr1-xyz", tmp_path / "root", cache_dir=tmp_path / "cache",
                       confirm=lambda message: next(answers))
    assert (tmp_path / "root" / "tum_fr1_xyz" / "rgb.txt").read_bytes() == tum[1]["rgb.txt"]
    code, out, err = fetch_cli(capsys, tmp_path, "tum-fr1-xyz", "--yes", "--overwrite")
    assert code == 0, err


def test_missing_member_and_corrupt_archive(capsys, tmp_path, server, tum):
    data, _ = tum_archive(drop="groundtruth.txt")
    server.files["/mirror/rgbd_dataset_freiburg1_xyz.tgz"] = data
    code, out, err = fetch_cli(capsys, tmp_path, "tum-fr1-xyz", "--keep-archive")
    assert code == 2 and err.count("\n") == 1
    archive = tmp_path / "cache" / "rgbd_dataset_freiburg1_xyz.tgz"
    assert err == (f"evsmap datasets: error: {archive}: has no member "
                   "rgbd_dataset_freiburg1_xyz/groundtruth.txt (expected the "
                   "rgbd_dataset_freiburg1_xyz archive)\n")
    assert not (tmp_path / "root").exists() or not any((tmp_path / "root").iterdir())
    assert leftovers(tmp_path) == ["cache/rgbd_dataset_freiburg1_xyz.tgz"]  # kept: not damaged
    archive.unlink()

    server.files["/mirror/rgbd_dataset_freiburg1_xyz.tgz"] = tum[0][: len(tum[0]) // 2]
    code, out, err = fetch_cli(capsys, tmp_path, "tum-fr1-xyz")
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"evsmap datasets: error: {archive}: not a readable .tgz archive (")
    assert err.endswith("; the download was deleted (run the command again to download it "
                        "anew)\n")
    assert leftovers(tmp_path) == [] or leftovers(tmp_path) == ["root"]


def test_content_check_failure_names_the_file(capsys, tmp_path, server, tum, monkeypatch):
    expected = dict(SAMPLES["tum-fr1-xyz"].expected)
    expected["groundtruth.txt"] = "0" * 64
    use(monkeypatch, "tum-fr1-xyz", expected=expected)
    code, out, err = fetch_cli(capsys, tmp_path, "tum-fr1-xyz")
    assert code == 2 and err.count("\n") == 1
    target = tmp_path / "root" / "tum_fr1_xyz"
    assert err.startswith(f"evsmap datasets: error: {target / 'groundtruth.txt'}: sha256 check "
                          "failed (got ")
    assert not target.exists()
    assert not any(p.name.startswith(".") for p in (tmp_path / "root").iterdir())


# -- 7-Scenes: a tiny redkitchen.zip holding seq-NN.zip -----------------------------------------
def sevenscenes_archive() -> tuple[bytes, dict[str, np.ndarray], dict[str, bytes]]:
    h, w = 48, 64
    y, x = np.mgrid[0:h, 0:w]
    colours, depths, poses = {}, {}, {}
    inner = io.BytesIO()
    with zipfile.ZipFile(inner, "w") as zf:
        for i in range(5):
            stem = f"frame-{i:06d}"
            rgb = np.stack([x * 3 + i, y * 4, np.full_like(x, 100 + 20 * i)], axis=2) \
                .astype(np.uint8)
            depth = (1000 + x * 10 + y * 5 + i).astype(np.uint16)
            depth[:2] = 65535  # invalid
            pose = np.eye(4)
            pose[:3, 3] = [0.1 * i, -0.2, 0.3]
            pose[0, 1], pose[1, 0] = 0.05 * i, -0.05 * i
            text = "".join("\t".join(f"{v:.7e}".replace("e-0", "e-00").replace("e+0", "e+00")
                                     for v in row) + "\t\n" for row in pose)
            zf.writestr(f"seq-01/{stem}.color.png", png_bytes(rgb))
            zf.writestr(f"seq-01/{stem}.depth.png", png_bytes(depth))
            zf.writestr(f"seq-01/{stem}.pose.txt", text)
            colours[stem], depths[stem] = rgb, depth
            poses[stem] = "".join(" ".join(f"{float(f'{v:.7e}'):.18e}" for v in row) + "\n"
                                  for row in pose).encode()
    other = io.BytesIO()
    with zipfile.ZipFile(other, "w") as zf:
        zf.writestr("seq-02/frame-000000.pose.txt", "1 0 0 0\n" * 4)
    outer = io.BytesIO()
    with zipfile.ZipFile(outer, "w") as zf:
        zf.writestr("redkitchen/TrainSplit.txt", "sequence1\n")
        zf.writestr("redkitchen/seq-02.zip", other.getvalue())
        zf.writestr("redkitchen/seq-01.zip", inner.getvalue())
    return outer.getvalue(), {"colour": colours, "depth": depths}, poses


def quarter_means(rgb: np.ndarray) -> tuple[float, ...]:
    a = rgb.astype(np.float64)
    h, w = a.shape[0] // 2, a.shape[1] // 2
    return tuple(float(q[..., c].mean()) for q in (a[:h, :w], a[:h, w:], a[h:, :w], a[h:, w:])
                 for c in range(3))


def test_fetch_sevenscenes(capsys, tmp_path, server, monkeypatch):
    data, arrays, poses = sevenscenes_archive()
    server.files["/mirror/redkitchen.zip"] = data
    intrinsics = b"".join(" ".join(f"{v:.18e}" for v in row).encode() + b"\n" for row in
                          [[585.0, 0.0, 320.0], [0.0, 585.0, 240.0], [0.0, 0.0, 1.0]])
    expected = {"camera-intrinsics.txt": sha(intrinsics)}
    for stem, rgb in list(arrays["colour"].items())[:3]:
        expected[f"{stem}.color.jpg"] = quarter_means(rgb)
        expected[f"{stem}.depth.png"] = array_digest(arrays["depth"][stem])
        expected[f"{stem}.pose.txt"] = sha(poses[stem])
    options = {**SAMPLES["sevenscenes-100"].options, "frames": 3}
    use(monkeypatch, "sevenscenes-100", options=options, expected=expected)
    # a large file of known (small) size: no --yes needed
    code, out, err = fetch_cli(capsys, tmp_path, "sevenscenes-100")
    assert code == 0, err
    folder = tmp_path / "root" / "sevenscenes_100"
    assert sorted(p.name for p in folder.iterdir()) == sorted([*expected, "evsmap-sample.json"])
    assert (folder / "camera-intrinsics.txt").read_bytes() == intrinsics
    for stem in list(poses)[:3]:
        assert (folder / f"{stem}.pose.txt").read_bytes() == poses[stem]
        assert np.array_equal(np.asarray(Image.open(folder / f"{stem}.depth.png")),
                              arrays["depth"][stem])
        with Image.open(folder / f"{stem}.color.jpg") as im:
            assert im.format == "JPEG" and im.size == (64, 48)
            assert np.abs(np.asarray(im, dtype=float) - arrays["colour"][stem]).mean() < 3
    manifest = json.loads((folder / "evsmap-sample.json").read_text())
    checks = {f["path"]: f["check"] for f in manifest["files"]}
    assert checks["frame-000000.color.jpg"] == "mean-rgb-2x2"
    assert checks["frame-000000.depth.png"] == "pixels"
    assert checks["frame-000000.pose.txt"] == "sha256"
    assert not list((tmp_path / "cache").iterdir())  # scratch files and archive gone

    # a sequence the archive does not have
    use(monkeypatch, "sevenscenes-100", options={**options, "sequence": "seq-07"})
    code, out, err = fetch_cli(capsys, tmp_path, "sevenscenes-100", "--overwrite")
    assert code == 2 and err == (f"evsmap datasets: error: {tmp_path / 'cache' / 'redkitchen.zip'}"
                                 ": has no member redkitchen/seq-07.zip (expected the 7-Scenes "
                                 "redkitchen archive)\n")
    assert (folder / "frame-000000.color.jpg").is_file()  # the old sample is untouched


# -- NYUv2: a tiny labelled .mat and the class mapping ----------------------------------------
def test_fetch_nyuv2(capsys, tmp_path, server, monkeypatch):
    src = tmp_path / "nyu_source"
    arrays = write_nyu_source(src, nyu_arrays(5))
    raw = arrays["depth"].copy()
    raw[:, 100:140, :] = 0.0  # the raw depth has holes
    with h5py.File(src / nyuv2.LABELLED_MAT, "r+") as f:
        f.create_dataset("rawDepths", data=raw.transpose(0, 2, 1))
    labelled = (src / nyuv2.LABELLED_MAT).read_bytes()
    mapping = (src / nyuv2.MAPPING_MAT).read_bytes()
    server.files["/mirror/nyu_depth_v2_labeled.mat"] = labelled
    server.files["/mirror/classMapping40.mat"] = mapping
    lut = np.concatenate([[255], nyu_map_class().astype(int) - 1]).astype(np.uint8)
    expected: dict = {}
    quantised = {}
    for index in (2, 4):
        k, fid = index - 1, f"{index:06d}"
        q = np.round(raw[k].astype(np.float64) * 5000)
        q[q > 65535] = 0
        quantised[fid] = q.astype(np.uint16)
        valid = quantised[fid][quantised[fid] > 0]
        expected[f"rgb/{fid}.png"] = array_digest(arrays["rgb"][k])
        expected[f"label40/{fid}.png"] = array_digest(lut[arrays["labels"][k]])
        expected[f"depth/{fid}.png"] = (valid.size / q.size, float(valid.min()),
                                        float(valid.max()), float(valid.mean()) + 0.4)
    sources = (SAMPLES["nyuv2-samples"].sources[0],
               dataclasses.replace(SAMPLES["nyuv2-samples"].sources[1], size=len(mapping),
                                   sha256=sha(mapping)))
    use(monkeypatch, "nyuv2-samples", sources=sources, options={"frames": (4, 2)},
        expected=expected)
    code, out, err = fetch_cli(capsys, tmp_path, "nyuv2-samples")
    assert code == 0, err
    folder = tmp_path / "root" / "nyuv2_samples"
    assert sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()) \
        == sorted([*expected, "evsmap-sample.json"])
    for fid, depth in quantised.items():
        assert np.array_equal(np.asarray(Image.open(folder / "depth" / f"{fid}.png")), depth)
    manifest = json.loads((folder / "evsmap-sample.json").read_text())
    assert [a["file"] for a in manifest["archives"]] == ["nyu_depth_v2_labeled.mat",
                                                         "classMapping40.mat"]
    from evsmap.registry import READERS

    seq = READERS.create("nyuv2", path=str(folder))
    assert seq.names == ["000002", "000004"]
    assert np.array_equal(seq[1].rgb, arrays["rgb"][3])

    # a depth mean off by more than the tolerance is refused
    expected["depth/000002.png"] = (*expected["depth/000002.png"][:3],
                                    expected["depth/000002.png"][3] + 2)
    use(monkeypatch, "nyuv2-samples", expected=expected)
    code, out, err = fetch_cli(capsys, tmp_path, "nyuv2-samples", "--overwrite")
    assert code == 2 and err.count("\n") == 1
    assert f"{folder / 'depth' / '000002.png'}: depth-stats check failed" in err


# -- listing, catalogue, start-up ---------------------------------------------------------------
def test_list(capsys, tmp_path, server, bag):
    code, out, err = run(capsys, "datasets", "fetch", "--out", str(tmp_path / "root"))
    assert code == 0 and err == ""
    lines = out.splitlines()
    assert lines[0] == f"samples under {tmp_path / 'root'}  (evsmap datasets fetch NAME)"
    assert [line.split()[:2] for line in lines[1:]] == [
        ["tum-fr1-xyz", "no"], ["sevenscenes-100", "no"], ["nyuv2-samples", "no"],
        ["lidar-odometry-bag", "no"]]
    assert "about 2.8 GB" in lines[3] and "nyu_depth_v2_labeled.mat (+1 more)" in lines[3]
    assert "300.0 kB" in lines[4]

    assert fetch_cli(capsys, tmp_path, "lidar-odometry-bag")[0] == 0
    (tmp_path / "root" / "tum_fr1_xyz").mkdir()
    code, out, _ = run(capsys, "datasets", "fetch", "--list", "--json", "--out",
                       str(tmp_path / "root"))
    listed = {r["name"]: r for r in json.loads(out)["samples"]}
    assert listed["lidar-odometry-bag"]["present"] is True
    assert listed["lidar-odometry-bag"]["fetched"] is not None
    assert listed["tum-fr1-xyz"]["present"] is True and listed["tum-fr1-xyz"]["fetched"] is None
    assert listed["nyuv2-samples"]["present"] is False
    assert listed["tum-fr1-xyz"]["sources"][0]["url"].startswith("https://cvg.cit.tum.de/")

    code, _, err = run(capsys, "datasets", "fetch", "kitti")
    assert code == 2 and "invalid choice: 'kitti'" in err and err.count("\n") == 1


def test_catalogue_sources_are_https_and_pinned():
    for sample in SAMPLES.values():
        assert sample.sources and sample.expected, sample.name
        for src in sample.sources:
            assert src.url.startswith("https://"), src.url
            assert isinstance(src, Source)
    bag = SAMPLES["lidar-odometry-bag"].sources[0]
    assert bag.size == 3835840 and "/74c0b5f9d50bd45bcb6ed8e44718cd60924c13d0/" in bag.url


@pytest.mark.parametrize("name", list(SAMPLES))
def test_catalogue_matches_the_real_samples(name):
    path = require_sample(name)
    sample = SAMPLES[name]
    values = samples.compute_expected(sample, path)
    assert set(values) == set(sample.expected)
    bad = [rel for rel, v in values.items()
           if not samples.check_matches(sample.rule_for(rel), sample.expected[rel], v)]
    assert bad == []


def test_the_expected_values_are_package_data(tmp_path):
    """The catalogue's expected values come from samples_expected.json, which the package ships
    and :func:`~evsmap.samples_expected.write_expected` writes back unchanged."""
    import tomllib

    from evsmap import samples_expected

    values = samples_expected.load_expected()
    assert {name: SAMPLES[name].expected for name in SAMPLES} == values
    assert isinstance(values["nyuv2-samples"]["depth/000433.png"], tuple)
    copy = tmp_path / "expected.json"
    samples_expected.write_expected(values, copy)
    assert copy.read_text() == samples_expected.DATA_FILE.read_text()
    assert samples_expected.load_expected(copy) == values
    root = Path(samples_expected.__file__).resolve().parents[1]
    package_data = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"]["evsmap"]
    assert samples_expected.DATA_FILE.name in package_data


def test_the_command_line_module_stays_light():
    code = ("import sys, evsmap.cli.datasets_cmd, evsmap.fetch, evsmap.samples; "
            "heavy = [m for m in ('torch', 'open3d', 'h5py', 'scipy') if m in sys.modules]; "
            "print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert out.strip() == "[]"


@pytest.mark.parametrize("at", [150_000, 299_999])
def test_ctrl_c_keeps_the_part_file_and_the_next_call_resumes(capsys, tmp_path, server, bag, at):
    from evsmap.interrupt import handle_signals

    server.interrupt_at["/mirror/test.bag"] = at
    with handle_signals():  # as the command line runs it (a test's main() keeps pytest's)
        code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag")
    assert code == 130, err
    assert err.startswith("evsmap datasets: interrupted (Ctrl-C); a partial download is kept")
    part = tmp_path / "cache" / "test.bag.part"
    assert not (tmp_path / "root").exists()
    # the signal may land before the body is read (no .part yet); what was kept is a prefix
    kept = part.stat().st_size if part.exists() else 0
    assert part.read_bytes() == BAG[:kept] if part.exists() else True

    code, out, err = fetch_cli(capsys, tmp_path, "lidar-odometry-bag")
    assert code == 0, err
    if 0 < kept < len(BAG):
        assert server.gets("/mirror/test.bag")[-1] == f"bytes={kept}-"
    assert (tmp_path / "root" / "ros" / "lidar_odometry.bag").read_bytes() == BAG
    assert not part.exists()
