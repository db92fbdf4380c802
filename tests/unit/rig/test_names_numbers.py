"""The names rule (rig/core/names.py), the config number types (rig/core/numbers.py) and the output-folder
check (rig/core/paths.py), on their own."""

from __future__ import annotations

import os
from typing import Annotated, get_args, get_origin

import pydantic
import pytest

from drivers import registry
from rig import config
from rig.core import names, numbers
from rig.core.errors import ConfigError
from rig.core.paths import calibration_file, inside, session_file


@pytest.mark.parametrize("good", ["m0", "MMC-0", "a.b_c", "7", "x" * 64])
def test_names_that_follow_the_rule_are_their_own_file_stem(good):
    assert names.check_name(good) == good
    assert names.file_stem(good) == good


@pytest.mark.parametrize("bad", ["", "../x", "/etc/passwd", "a/b", "a\\b", ".hidden", "-rf", "a b", "mägo",
                                 "a\nb", "a\x00b", "x" * 65, "..", "C:x"])
def test_names_outside_the_rule_are_refused(bad):
    with pytest.raises(ValueError):
        names.check_name(bad)


def test_safe_name_is_a_pydantic_type():
    adapter = pydantic.TypeAdapter(names.SafeName)
    assert adapter.validate_python("dut-1") == "dut-1"
    for bad in ("../a", 12, None):
        with pytest.raises(pydantic.ValidationError):
            adapter.validate_python(bad)


@pytest.mark.parametrize("hostile", ["../../x", "/abs/path", "a/b\\c", "\x00", "ä" * 300, "..", ".", "*/"])
def test_transformations_give_plain_names_from_anything(hostile):
    stem, ident, guard = names.file_stem(hostile), names.c_identifier(hostile), names.header_guard(hostile)
    assert stem and "/" not in stem and "\\" not in stem and not stem.startswith(".")
    assert len(stem) <= names.MAX_FILE_STEM
    assert ident.isidentifier() and ident.isascii() and not ident[0].isdigit() and not ident.startswith("_")
    assert len(f"{ident}_apply") <= 63 and len(guard) <= 63 and guard.isidentifier() and guard.isupper()


def test_names_differing_only_in_non_ascii_letters_stay_apart():
    a, b = "mag_ä", "mag_ö"
    assert names.file_stem(a) != names.file_stem(b)
    assert names.c_identifier(a) != names.c_identifier(b)
    assert names.header_guard(a) != names.header_guard(b)
    assert names.collision([a, b]) is None
    long_a, long_b = "x" * 200 + "a", "x" * 200 + "b"  # cut short, told apart by their hash
    assert names.c_identifier(long_a) != names.c_identifier(long_b)


@pytest.mark.parametrize("pair, what", [(["m0", "M0"], "file name"), (["m-0", "m_0"], "C symbol"),
                                        (["a.b", "a-b"], "C symbol")])
def test_names_that_collide_after_transformation_are_named(pair, what):
    index, message = names.collision(pair)
    assert index == 1 and repr(pair[0]) in message and repr(pair[1]) in message and what in message
    with pytest.raises(ValueError, match=what):
        names.check_unique(pair)


@pytest.mark.parametrize("tp, value", [
    (numbers.FiniteFloat, True), (numbers.FiniteFloat, float("inf")), (numbers.FiniteFloat, float("nan")),
    (numbers.FiniteFloat, "nan"), (numbers.FiniteFloat, "abc"), (numbers.FiniteFloat, None),
    (numbers.PositiveFloat, 0), (numbers.NonNegativeFloat, -1e-9),
    (numbers.Count(100_000), True), (numbers.Count(100_000), 1e14), (numbers.Count(100_000), 2.5),
    (numbers.Count(100_000), 0), (numbers.Count(100_000), "1e14"),
    (numbers.Vec3, [1, 2]), (numbers.Vec3, [1, 2, float("inf")]), (numbers.Vec3, [1, True, 3]),
    (numbers.bounded_vec3(1e6), [0, 0, 2e6]),
])
def test_number_types_refuse(tp, value):
    with pytest.raises(pydantic.ValidationError):
        pydantic.TypeAdapter(tp).validate_python(value)


@pytest.mark.parametrize("tp, value, expected", [
    (numbers.FiniteFloat, 3, 3.0), (numbers.FiniteFloat, "1.0e3", 1000.0),  # YAML 1.1 reads 1.0e3 as text
    (numbers.PositiveFloat, 1e-300, 1e-300), (numbers.Count(10), 10, 10), (numbers.Count(10), 4.0, 4),
    (numbers.Vec3, [1, 2, 3], (1.0, 2.0, 3.0)), (numbers.bounded_vec3(1e6), [0, -1e6, 5], (0.0, -1e6, 5.0)),
])
def test_number_types_take(tp, value, expected):
    assert pydantic.TypeAdapter(tp).validate_python(value) == expected


def _models(tp, seen: set) -> None:
    """Every pydantic model (or pydantic dataclass) reachable from a type."""
    if isinstance(tp, type) and (issubclass(tp, pydantic.BaseModel) or hasattr(tp, "__pydantic_fields__")):
        if tp in seen:
            return
        seen.add(tp)
        for field in tp.__pydantic_fields__.values():
            _models(field.annotation, seen)
    for arg in get_args(tp):
        _models(arg, seen)


def _plain_numbers(tp) -> list:
    """The bare int/float leaves of a field type: ones no validator of their own refuses true/inf/NaN for."""
    if tp in (int, float):
        return [tp]
    args = get_args(tp)
    if get_origin(tp) is Annotated and any(isinstance(m, pydantic.BeforeValidator) for m in args[1:]):
        return []
    return [leaf for arg in args for leaf in _plain_numbers(arg)]


def test_every_number_field_of_the_config_models_has_a_finite_type():
    """Station and plan models: each number is a rig/core/numbers.py type; a driver's options model (which
    cannot import rig) is covered by drivers/registry.py's Options base instead."""
    seen: set = set()
    _models(config.Station, seen)
    _models(config.Plan, seen)
    assert config.Coils in seen and config.TruthSpec in seen and config.Stability in seen
    bare = []
    for model in seen:
        if issubclass(model, registry.Options):
            continue
        for name, field in model.__pydantic_fields__.items():
            metadata_checks = any(isinstance(m, pydantic.BeforeValidator) for m in field.metadata)
            strict = any(getattr(m, "strict", False) for m in field.metadata)
            if _plain_numbers(field.annotation) and not (metadata_checks or strict):
                bare.append(f"{model.__name__}.{name}")
    assert bare == []


@pytest.mark.parametrize("value, problem", [
    (True, "expected a number, got true"), (float("nan"), "finite"), ("   -Infinity   ", "finite"),
    ([1.0, float("inf")], "finite"),
])
def test_driver_options_refuse_booleans_and_non_finite_numbers(value, problem):
    from drivers.chamber import ChamberLimits
    from drivers.turntable import TurntableOptions

    limits = {"min_setpoint_c": -40, "max_setpoint_c": 85, "max_ramp_c_per_min": 5}
    model, key, data = ((TurntableOptions, "az_limits_deg", {}) if isinstance(value, list)
                        else (ChamberLimits, "max_ramp_c_per_min", limits))
    with pytest.raises(pydantic.ValidationError) as exc:
        model.model_validate({**data, key: value})
    cause = exc.value.errors()[0]["ctx"]["error"]
    assert isinstance(cause, registry.KeyPathError) and cause.path[0] == key and problem in cause.message


def test_output_paths_stay_inside_the_output_folder(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    assert session_file(out, "demo", "20260101-000000") == out / "demo-20260101-000000.session"
    session = out / "demo-1.session"
    assert calibration_file(session, "mmc0", "t24") == out / "demo-1.mmc0.t24.yaml"
    assert calibration_file(session, "../../evil", "t24").parent == out  # the name is made a plain stem
    for bad in ("../x", "/tmp/x", "a/../../x", ""):
        with pytest.raises(ConfigError, match="outside the output folder"):
            inside(out, bad)


def test_a_symlink_out_of_the_output_folder_is_refused(tmp_path):
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    os.symlink(elsewhere / "target.session", out / "demo-1.session")
    with pytest.raises(ConfigError, match="outside the output folder"):
        session_file(out, "demo", "1")
    os.symlink(elsewhere, out / "link")
    with pytest.raises(ConfigError, match="outside the output folder"):
        inside(out, "link/x.png")
