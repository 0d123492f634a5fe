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
