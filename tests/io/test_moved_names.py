"""Names that moved out of tactojax.io to their stage keep working there, with a DeprecationWarning."""

import pytest

import tactojax.io
import tactojax.localize.evaluation
import tactojax.simulate
import tactojax.storage

MOVED = {
    "dataset_metadata": tactojax.simulate,
    "load_test_episodes": tactojax.localize.evaluation,
    "sensor_metadata": tactojax.simulate,
    "simulate_to_dataset": tactojax.simulate,
}


@pytest.mark.parametrize("name", sorted(MOVED))
def test_a_moved_name_warns_and_is_the_new_one(name):
    with pytest.warns(DeprecationWarning, match=f"{MOVED[name].__name__}.{name}"):
        old = getattr(tactojax.io, name)
    assert old is getattr(MOVED[name], name)
    assert name not in tactojax.io.__all__


def test_storage_names_are_re_exported_by_io_without_warning(recwarn):
    for name in tactojax.storage.__all__:
        if hasattr(tactojax.io, name):
            assert getattr(tactojax.io, name) is getattr(tactojax.storage, name)
    assert {"open_dataset", "load_mesh", "read_test_grasps", "CorruptCheckpointError"} <= set(tactojax.io.__all__)
    assert not [w for w in recwarn if issubclass(w.category, DeprecationWarning)]


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        tactojax.io.nothing_here  # noqa: B018
