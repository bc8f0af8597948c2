"""usdbtf.jsontext: readable JSON for manifests and compressed-BTF metadata."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from usdbtf import jsontext

_scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6),
                     st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=6))
_docs = st.recursive(_scalars, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                       st.dictionaries(st.text(max_size=5), inner, max_size=5)),
                     max_leaves=30)


@given(_docs)
@settings(max_examples=300, deadline=None)
def test_parses_to_what_the_standard_encoder_writes(doc):
    # Same values, key order and float repr as json.dumps; strings with brackets, quotes,
    # braces and "], [" inside them included.
    text = jsontext.dumps(doc)
    assert json.loads(text) == json.loads(json.dumps(doc))
    assert list(_walk_keys(json.loads(text))) == list(_walk_keys(doc))


def _walk_keys(obj):
    if isinstance(obj, dict):
        for key, value in obj.items():
            yield key
            yield from _walk_keys(value)
    elif isinstance(obj, list):
        for value in obj:
            yield from _walk_keys(value)


def test_strings_that_look_like_structure_survive():
    doc = {"rows": [["], [", "a"], ["{", "}"]], "flat": ["[1, 2]", '"'], "objs": [{"image": "x], [y.png"}]}
    assert json.loads(jsontext.dumps(doc)) == doc


def test_layout_of_a_manifest_like_document():
    samples = [{"image": f"{i:05d}.png", "view": [10.0 * i, 0.0], "light": [15.0, 30.0 * i]} for i in range(4)]
    doc = {"format": "btf-manifest/1", "width": 8, "matrix": np.eye(3).tolist(), "samples": samples,
           "scale": [0.5, 0.25]}
    lines = jsontext.dumps(doc).splitlines()
    # One sample per line, one matrix row per line, a flat list on its key's line.
    assert lines.count(' "samples": [') == 1
    assert sum(line.startswith('  {"image": ') for line in lines) == 4
    assert '  [1.0, 0.0, 0.0],' in lines and '  [0.0, 0.0, 1.0]' in lines
    assert ' "scale": [0.5, 0.25]' in lines
    assert len(lines) == 1 + 2 + 5 + 6 + 1 + 1     # braces, scalars, matrix, samples, scale


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_numbers_are_refused(bad):
    for doc in ({"a": bad}, {"a": [1.0, bad]}, {"a": [[1.0], [bad]]}, {"a": [{"b": bad}]}):
        with pytest.raises(ValueError):
            jsontext.dumps(doc)
