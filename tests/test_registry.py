import pytest

from evsmap.errors import DuplicateNameError, EvsmapError, UnknownNameError
from evsmap.registry import READERS, Registry, get_reader, list_readers


def make_registry() -> Registry:
    reg = Registry("widget")

    @reg.register("alpha-net", description="first")
    def alpha(*, size: int = 3) -> tuple:
        return ("alpha", size)

    @reg.register("beta-net")
    def beta(*, depth: bool = False) -> tuple:
        """Second widget.

        More text that is not the description."""
        return ("beta", depth)

    return reg


def test_create_passes_keyword_config():
    reg = make_registry()
    assert reg.create("alpha-net", size=7) == ("alpha", 7)
    assert reg.names() == ["alpha-net", "beta-net"]
    assert reg.get("beta-net").description == "Second widget."


def test_duplicate_name_raises():
    reg = make_registry()
    with pytest.raises(DuplicateNameError, match="alpha-net.*already registered"):
        reg.add("alpha-net", lambda **kw: None)


def test_unknown_name_lists_known_and_closest():
    reg = make_registry()
    with pytest.raises(UnknownNameError) as info:
        reg.get("alpha-nte")
    msg = str(info.value)
    assert "did you mean 'alpha-net'" in msg
    assert "alpha-net, beta-net" in msg


def test_unknown_option_is_named():
    reg = make_registry()
    with pytest.raises(EvsmapError, match="no option 'colour'.*accepted: size"):
        reg.create("alpha-net", colour="red")


def test_positional_factories_are_refused():
    reg = Registry("widget")
    with pytest.raises(TypeError, match="keyword-only"):
        reg.add("gamma", lambda size: size)


def test_builtin_readers_registered():
    assert {"tum", "synthetic"} <= set(list_readers())
    assert "tum" in READERS
    seq = get_reader("synthetic", frames=2, width=32, height=24)
    assert len(seq) == 2


def test_options_of_the_wrong_type_are_one_clear_error():
    from evsmap.errors import EvsmapError
    from evsmap.registry import UPDATERS

    with pytest.raises(EvsmapError, match="option psi must be a number, got 'abc'"):
        UPDATERS.create("multiclass-bayes", psi="abc")
    with pytest.raises(EvsmapError, match="option discretize must be true or false"):
        UPDATERS.create("orgb", discretize="yes")
    with pytest.raises(EvsmapError, match="option clamp_min must be a number"):
        UPDATERS.create("classic-semantic", clamp_min="low")
    # numbers given as integers, None where the annotation allows it, still pass
    UPDATERS.create("multiclass-bayes", psi=2, theta=1)
    UPDATERS.create("classic-semantic", clamp_min=None)


# -- capabilities declared once (issue 55) ---------------------------------------------------
def test_entries_have_no_parameter_probe():
    """Callers read what a plug-in takes from its entry's fields; there is no signature left
    to probe."""
    from evsmap.registry import Entry

    assert not hasattr(Entry, "parameters")


def test_takes_of_an_undeclared_factory_are_derived_once_at_registration(monkeypatch):
    import inspect

    from evsmap.registry import Takes

    reg = Registry("reader")

    @reg.register("folders")
    def folders(*, path: str, split: str = "all", frames: int = 3) -> tuple:
        return (path, split, frames)

    entry = reg.get("folders")
    assert entry.takes == Takes(path=True, split=True)
    assert list(entry.options) == ["path", "split", "frames"]
    assert entry.options["path"].required and entry.defaults() == {"split": "all", "frames": 3}

    READERS.names()  # the built-in plug-ins registered before signatures are forbidden

    def no_signature(obj, *args, **kwargs):
        raise AssertionError("a factory's signature read after its registration")

    monkeypatch.setattr(inspect, "signature", no_signature)
    assert reg.get("folders").takes.path and not reg.get("folders").takes.limit
    assert reg.create("folders", path="x", frames=1) == ("x", "all", 1)
    with pytest.raises(EvsmapError, match="no option 'limit'"):
        reg.create("folders", path="x", limit=1)


def test_declared_takes_must_match_the_factory():
    from evsmap.registry import NETWORK, Takes

    reg = Registry("segmenter")
    with pytest.raises(TypeError, match="declares takes.weights but its factory has no option"):
        reg.add("plain", lambda *, k=3: k, takes=Takes(weights=True))
    with pytest.raises(TypeError, match="its factory takes 'backend'; declare it"):
        reg.add("half", lambda *, weights=None, backend="torch", input_size=None: 0,
                takes=Takes(weights=True, input_size=True))
    assert "plain" not in reg.names() and "half" not in reg.names()
    reg.add("net", lambda *, weights=None, backend="torch", input_size=None: 0, takes=NETWORK)
    reg.add("open", lambda **options: options, takes=NETWORK)  # **options: may take more
    assert reg.get("net").takes == reg.get("open").takes == NETWORK
    assert reg.get("open").any_option and reg.create("open", weights="w") == {"weights": "w"}


def test_builtin_plugins_declare_what_they_take():
    from evsmap.registry import NETWORK, OCTREE, SEGMENTERS, UPDATERS, Takes

    dataset = Takes(path=True, split=True, limit=True)
    assert READERS.get("synthetic").takes == Takes()
    assert READERS.get("tum").takes == Takes(path=True, camera=True)
    assert READERS.get("rosbag").takes == Takes(path=True, limit=True)
    assert READERS.get("nyuv2").takes == READERS.get("sunrgbd").takes == dataset
    assert READERS.get("cityscapes").takes == Takes(path=True, split=True, limit=True,
                                                    resolution=True)
    assert SEGMENTERS.get("feagnet-v1").takes == NETWORK
    assert SEGMENTERS.get("oracle").takes == Takes()
    assert UPDATERS.get("multiclass-bayes").takes == UPDATERS.get("orgb").takes == OCTREE
    assert UPDATERS.get("orgb").options["resolution"].default == 0.05


def test_only_a_network_sets_an_input_size():
    from evsmap.errors import InvalidDataError
    from evsmap.registry import SEGMENTERS

    oracle = SEGMENTERS.create("oracle")
    assert oracle.input_size is None
    with pytest.raises(InvalidDataError, match="no input size"):
        oracle.set_input_size((48, 64))
    network = SEGMENTERS.create("feagnet-s", input_size=(64, 96))
    network._session = object()  # as an ONNX Runtime session built at 64x96
    network.set_input_size((96, 128))
    assert network.input_size == (96, 128) and network._session is None
