"""What evsmap reads of a plug-in it reads through the interface, not by probing attribute
names: a segmenter's network threads, a sequence's folder, a segmenter's name in an error."""

from __future__ import annotations

import argparse

import pytest

from evsmap.data import FrameList, Intrinsics, Sequence
from evsmap.errors import EvsmapError
from evsmap.runner.mapping_labels import sequence_identity
from tests.test_interfaces import DepthBands


def test_a_segmenter_that_is_not_a_network_has_no_network_threads():
    assert DepthBands().network_threads is None


def test_a_network_segmenter_states_its_threads():
    from evsmap.registry import get_segmenter

    seg = get_segmenter("feagnet-v1")
    seg.set_threads(2)
    assert seg.network_threads == 2


class _FromDisk(Sequence):
    """A plug-in reader's sequence: it says where its frames are by setting ``folder``."""

    def __init__(self, folder, *, root=None) -> None:
        super().__init__("from-disk", Intrinsics(10.0, 10.0, 4.0, 3.0, 8, 6))
        self.folder = folder
        self.root = root  # an attribute of its own: not read by the cache

    def __len__(self) -> int:
        return 0

    def frame(self, index: int):
        raise IndexError(index)


def test_the_cache_identity_of_a_sequence_is_its_folder(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    st = frames.stat()
    assert sequence_identity(_FromDisk(frames)) == \
        f"{frames.resolve()}:{st.st_mtime_ns}:{st.st_size}"


def test_a_sequence_without_a_folder_is_known_by_its_name(tmp_path):
    assert sequence_identity(_FromDisk(None, root=tmp_path)) == "from-disk"
    in_memory = FrameList("held", Intrinsics(10.0, 10.0, 4.0, 3.0, 8, 6), [])
    assert in_memory.folder is None and sequence_identity(in_memory) == "held"


def test_a_reader_sets_its_folder(tmp_path, monkeypatch):
    """TUM's reader on the synthetic room's cached rendering: the cache identity is the folder
    the frames are read from, as it was when the runner probed a ``root`` attribute."""
    from evsmap.registry import READERS
    from evsmap.synth.cached import CachedSynthetic

    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path / "cache"))
    rendered = CachedSynthetic(frames=2, width=80, height=60).folder
    tum = READERS.create("tum", path=str(rendered))
    assert tum.folder == rendered
    st = rendered.stat()
    assert sequence_identity(tum) == f"{rendered.resolve()}:{st.st_mtime_ns}:{st.st_size}"


def test_a_placement_refused_names_the_segmenter_as_registered():
    args = argparse.Namespace(device="cpu", precision="fp16")
    from evsmap.cli.precision import apply_precision

    with pytest.raises(EvsmapError, match=r"^--precision fp16: segmenter 'depth-bands' is not a "
                                          r"network"):
        apply_precision(args, DepthBands(), None, name="depth-bands")
