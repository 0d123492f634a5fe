"""Measured memory: the peak of a block, from its start."""

import numpy as np

from evsmap.measure.memory import PeakMemory, peak_rss, resident_parts


def test_peak_of_a_block_sees_a_numpy_allocation_that_is_gone_by_its_end():
    # in a fresh process: in the test session's, freed heap may already hold the 80 MB
    import json
    import subprocess
    import sys

    code = ("import json, numpy as np\n"
            "from evsmap.measure.memory import PeakMemory, current_rss\n"
            "with PeakMemory() as m:\n"
            "    a = np.ones(80_000_000 // 8)\n"
            "    del a\n"
            "print(json.dumps({**m.as_dict(), 'now': current_rss()}))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    m = json.loads(r.stdout)
    assert m["scope"] == "block"  # Linux lets the peak be reset
    assert 75e6 < m["added_bytes"] < 120e6
    assert m["now"] < m["peak_rss_bytes"]


def test_a_later_block_does_not_inherit_an_earlier_peak():
    with PeakMemory():
        a = np.ones(100_000_000 // 8)
        del a
    with PeakMemory() as small:
        b = np.ones(5_000_000 // 8)
        del b
    assert small.added_bytes < 40e6
    assert peak_rss() >= small.start_rss_bytes


def _heap_kept_after_two_frees(fixed: bool) -> int:
    import subprocess
    import sys

    code = ("import numpy as np\n"
            "from evsmap.measure.memory import current_rss, fixed_mmap_threshold, "
            "MMAP_THRESHOLD_MIN\n"
            f"if {fixed}: assert fixed_mmap_threshold(MMAP_THRESHOLD_MIN)\n"
            "before = current_rss()\n"
            "a = np.ones(12_000_000 // 8); del a\n"
            "b = np.ones(12_000_000 // 8); del b\n"
            "print(current_rss() - before)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return int(r.stdout)


def test_a_fixed_mmap_threshold_returns_freed_blocks_that_the_dynamic_one_keeps():
    # glibc's default: the first free of a mapped 12 MB block raises the threshold above it, so
    # the second 12 MB comes from the heap and stays resident after its free
    assert _heap_kept_after_two_frees(fixed=False) > 10e6
    assert _heap_kept_after_two_frees(fixed=True) < 2e6


def test_resident_parts_tell_a_mapped_file_from_allocated_memory(tmp_path):
    import mmap

    import pytest

    if resident_parts() is None:
        pytest.skip("the kernel does not split the RSS (not Linux >= 4.5)")
    size = 32 * 2**20
    path = tmp_path / "pages.bin"
    path.write_bytes(b"\1" * size)
    before = resident_parts()
    with path.open("rb") as fh, mmap.mmap(fh.fileno(), size, access=mmap.ACCESS_READ) as view:
        total = sum(view[i] for i in range(0, size, 4096))  # one read per page
        mapped = resident_parts()
    assert total == size // 4096
    assert mapped["file"] - before["file"] >= 0.9 * size
    assert abs(mapped["anon"] - before["anon"]) < 0.25 * size

    # fresh private pages, written one by one (not the heap, which may hold freed pages already)
    with mmap.mmap(-1, size, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS) as block:
        for i in range(0, size, 4096):
            block[i] = 1
        allocated = resident_parts()
    assert allocated["anon"] - before["anon"] >= 0.9 * size
    assert allocated["file"] - before["file"] < 0.25 * size
