"""Measured memory: the peak of a block, from its start."""

import numpy as np

from evsmap.measure.memory import PeakMemory, peak_rss


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
