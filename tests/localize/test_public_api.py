"""tactojax.localize keeps the library's answer at the top (the belief, the live loop, identification);
the paper's baselines, the evaluation and active touch are public submodules. Names that moved
keep working at the old path, with a DeprecationWarning."""

import importlib

import pytest

import tactojax.localize

SUBMODULES = ("active", "baselines", "evaluation")


@pytest.mark.parametrize("name", sorted(tactojax.localize._MOVED))
def test_a_moved_name_warns_and_is_the_new_one(name):
    module = importlib.import_module(tactojax.localize._MOVED[name])
    with pytest.warns(DeprecationWarning, match=f"{module.__name__}.{name}"):
        old = getattr(tactojax.localize, name)
    assert old is getattr(module, name)
    assert name in module.__all__


def test_every_public_name_has_one_home_and_the_top_stays_small(recwarn):
    homes = {"": set(tactojax.localize.__all__)}
    for sub in SUBMODULES:
        homes[sub] = set(importlib.import_module(f"tactojax.localize.{sub}").__all__)
    names = [name for found in homes.values() for name in found]
    assert len(names) == len(set(names)), "a name is public in two places"
    assert len(homes[""]) <= 30
    assert set(tactojax.localize._MOVED) <= set(names) - homes[""]
    for name in tactojax.localize.__all__:
        getattr(tactojax.localize, name)
    assert not [w for w in recwarn if issubclass(w.category, DeprecationWarning)]


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        tactojax.localize.nothing_here  # noqa: B018
