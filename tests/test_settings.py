"""A stage's settings: its defaults with a caller's overrides, nested blocks merged key by key."""

from __future__ import annotations

from stereogeo_cli.sequence import colmap
from stereogeo_cli.settings import resolve


def test_overriding_one_key_of_a_nested_block_keeps_its_other_defaults():
    conf = resolve(colmap.default_conf, {"mapping": {"ba_global_max_num_iterations": 50}, "overlap": 5})
    assert conf["overlap"] == 5
    assert conf["mapping"] == {**colmap.default_conf["mapping"], "ba_global_max_num_iterations": 50}
    assert conf["mapper"] == colmap.default_conf["mapper"]
    assert colmap.default_conf["mapping"]["ba_global_max_num_iterations"] == 25  # the defaults unchanged


def test_the_result_shares_no_nested_block_with_the_defaults_or_the_overrides():
    defaults = {"block": {"a": 1}, "slot": {}}
    overrides = {"slot": {"b": {"c": 2}}}
    conf = resolve(defaults, overrides)
    conf["block"]["a"] = 9
    conf["slot"]["b"]["c"] = 9
    assert defaults == {"block": {"a": 1}, "slot": {}} and overrides == {"slot": {"b": {"c": 2}}}
    assert resolve(defaults) == defaults and resolve(defaults, None) is not defaults
