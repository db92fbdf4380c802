"""calib/io/calfile.py writes lists of floats in one pass: the text is byte for byte what PyYAML's own safe
dumper writes, for every kind of float and for strings that look like floats, and it reads back."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from calib.io.calfile import _Dumper


def _document(rng) -> dict:
    specials = [0.0, -0.0, 1e-5, 1e20, -2.5e-300, float("nan"), float("inf"), float("-inf"), 3.0, 1e16]
    return {
        "covariance": rng.normal(size=(6, 6)).tolist(),
        "specials": specials,
        "mixed": [1.5, 2, "0.5", None, True],
        "look_alike": ["1.5", "1.0e-05", ".inf", "3.0"],
        "note": "0.5",
        "nested": {"a": [[1.0, -1.0], []], "b": rng.uniform(-1e9, 1e9, 5).tolist()},
    }


def test_the_float_lists_are_written_as_pyyamls_own_dumper_writes_them():
    rng = np.random.default_rng(3)
    for _ in range(5):
        doc = _document(rng)
        options = {"sort_keys": False, "default_flow_style": None, "width": 120}
        ours = yaml.dump(doc, Dumper=_Dumper, **options)
        assert ours == yaml.dump(doc, Dumper=yaml.SafeDumper, **options)
        back = yaml.safe_load(ours)
        assert back["look_alike"] == doc["look_alike"] and back["note"] == "0.5"  # strings stay strings
        assert np.array_equal(back["covariance"], doc["covariance"])
        assert np.isnan(back["specials"][5]) and back["specials"][6:8] == [float("inf"), float("-inf")]


def test_a_file_without_anchors_reads_the_same_through_libyaml_and_an_undefined_alias_is_refused(tmp_path):
    """calfile reads a text without "&" with libyaml's parser (no anchor, so no alias to refuse): the same
    data as the pure-Python loader that refuses aliases; an alias with no anchor is still a DataError."""
    from calib.errors import DataError
    from calib.io import calfile

    text = yaml.dump(_document(np.random.default_rng(5)), Dumper=_Dumper, sort_keys=False,
                     default_flow_style=None, width=120)
    assert "&" not in text
    fast, checked = calfile._parse_yaml(text), yaml.load(text, Loader=calfile._NoAliasLoader)
    assert repr(fast) == repr(checked)  # nan == nan is False: compared as text
    path = tmp_path / "alias.yaml"
    path.write_text("format: magrig-calibration\nmodel: t24\nparams: *nowhere\n")
    with pytest.raises(DataError, match="line 3") as caught:
        calfile.load(path)
    assert str(path) in str(caught.value)
