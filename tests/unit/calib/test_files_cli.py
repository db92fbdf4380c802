"""Calibration files, the CSV contract and `rig refit` / `rig apply`, including every bad-input path."""

import json
import sqlite3

import numpy as np
import pytest
import yaml

import calib
from calib import synthetic
from calib.io import calfile, csvio
from rig.cli import main
from rig.core.errors import DataError


@pytest.fixture
def t24_csv(tmp_path):
    ds, truth = synthetic.t24_dataset(np.random.default_rng(1), samples_per_point=4)
    path = tmp_path / "t24.csv"
    ds.group = None
    csvio.write_csv(path, {**csvio.contract_columns(ds), "note": np.array(["coil"] * len(ds), dtype=object)})
    return path, ds, truth


def _run(capsys, *argv):
    code = main(list(map(str, argv)))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_calibration_file_round_trips_exactly(tmp_path, suffix):
    ds, _ = synthetic.t24_dataset(np.random.default_rng(2))
    cal = calib.fit(ds, "t24", robust=True)
    path = tmp_path / f"cal{suffix}"
    calfile.save(cal, path)
    back = calfile.load(path)
    assert back.to_dict() == cal.to_dict()
    for name, value in cal.params.items():
        assert np.array_equal(back.params[name], value)
    np.testing.assert_array_equal(back.apply(ds.h_nt, ds.temp_c), cal.apply(ds.h_nt, ds.temp_c))


def test_corrupted_and_foreign_calibration_files_name_the_key(tmp_path):
    ds, _ = synthetic.p12_dataset(np.random.default_rng(3))
    good = calib.fit(ds, "p12").to_dict()
    cases = {
        "model": ({**good, "model": "t99"}, "key 'model'"),
        "shape": ({**good, "params": {**good["params"], "k": [1.0, 2.0]}}, "key 'params.k' has shape"),
        "missing": ({**good, "std_errors": {"k": [0, 0, 0]}}, "'std_errors.angles_deg' is missing"),
        "text": ({**good, "params": {**good["params"], "h0_nt": ["a", 1, 2]}},
                 "'params.h0_nt' is not numeric"),
    }
    for name, (data, expected) in cases.items():
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(data))
        with pytest.raises(DataError, match=expected) as info:
            calfile.load(path)
        assert str(path) in str(info.value)
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps(good)[:-20])
    with pytest.raises(DataError, match=r"broken.json: line 1: not valid JSON"):
        calfile.load(broken)


def test_read_csv_with_column_map_and_units(tmp_path):
    path = tmp_path / "real.csv"
    path.write_text("t_s,mx_gauss,my_gauss,mz_gauss\n0.1,0.25,-0.5,0.125\n0.2,0.5,0.0,-1e-3\n")
    ds = csvio.read_csv(
        path, raw_unit="gauss", columns=csvio.parse_column_map("hx=mx_gauss,hy=my_gauss,hz=mz_gauss")
    )
    np.testing.assert_allclose(ds.h_nt, [[25000, -50000, 12500], [50000, 0, -100]])
    assert ds.temp_c is None and ds.ref_nt is None
    assert list(ds.columns) == ["t_s", "mx_gauss", "my_gauss", "mz_gauss"]
    assert ds.source["rows_total"] == 2 and len(ds.source["sha256"]) == 64
    assert csvio.nt_per_raw_unit("counts", "1090/gauss") == pytest.approx(1e5 / 1090)
    assert csvio.nt_per_raw_unit("counts", "10/uT") == pytest.approx(100.0)
    assert csvio.nt_per_raw_unit("uT") == 1000.0


BAD_CSV = {
    "missing_column": ("hx,hy,temp\n1,2,3\n", "line 1: missing column 'hz'"),
    "non_numeric": ("hx,hy,hz\n1,2,3\n4,five,6\n", "line 3, column 'hy': 'five' is not a number"),
    "nan": ("hx,hy,hz\n1,2,3\n4,nan,6\n", "line 3\\), column 'hy': nan is not finite"),
    "inf": ("hx,hy,hz\n1,2,3\n4,5,inf\n", "column 'hz': inf is not finite"),
    "empty": ("", "empty file"),
    "header_only": ("hx,hy,hz\n", "no data rows"),
    "ragged": ("hx,hy,hz\n1,2,3\n4,5\n", "line 3: 2 cells, the header has 3"),
}


@pytest.mark.parametrize("case", sorted(BAD_CSV))
def test_bad_csv_gives_one_line_naming_file_and_place(tmp_path, capsys, case):
    text, expected = BAD_CSV[case]
    data = tmp_path / f"{case}.csv"
    data.write_text(text)
    out = tmp_path / "cal.yaml"
    code, _, err = _run(capsys, "refit", data, "--model", "p12", "-o", out)
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and str(data) in lines[0]
    assert __import__("re").search(expected, lines[0]), lines[0]
    assert "Traceback" not in err
    assert not out.exists() and not list(tmp_path.glob(".cal.yaml*"))


def test_refit_and_apply_end_to_end(t24_csv, tmp_path, capsys):
    path, ds, truth = t24_csv
    cal_path = tmp_path / "cal.yaml"
    code, out, err = _run(capsys, "refit", path, "--model", "t24", "-o", cal_path)
    assert code == 0, err
    assert "RMS after" in out and "kb_nt_per_c" in out and "10.0 degC" in out
    cal = calfile.load(cal_path)
    assert cal.source["path"] == str(path) and cal.source["rows_used"] == len(ds)
    assert cal.software_version == __import__("rig").__version__
    out_csv = tmp_path / "out.csv"
    code, _, err = _run(capsys, "apply", cal_path, path, "-o", out_csv)
    assert code == 0, err
    header = out_csv.read_text().splitlines()[0].split(",")
    assert header == ["hx", "hy", "hz", "temp", "ref_bx", "ref_by", "ref_bz", "note", "bx", "by", "bz"]
    result = csvio.read_csv(out_csv)
    assert len(result) == len(ds) and result.columns["note"][0] == "coil"
    calibrated = np.column_stack([result.columns[c] for c in ("bx", "by", "bz")])
    np.testing.assert_allclose(calibrated, cal.apply(ds.h_nt, ds.temp_c), rtol=1e-12)
    assert np.sqrt(np.mean((calibrated - ds.ref_nt) ** 2)) < 12.0


def test_refit_too_few_rows_and_singular_design(tmp_path, capsys):
    few = tmp_path / "few.csv"
    few.write_text("hx,hy,hz,temp,bx,by,bz\n" + "1,2,3,20,1,2,3\n" * 5)
    code, _, err = _run(capsys, "refit", few, "--model", "t24", "-o", tmp_path / "c.yaml")
    assert code != 0 and "5 samples, more than 8 needed" in err
    one_temp = tmp_path / "onetemp.csv"
    ds, _ = synthetic.t24_dataset(np.random.default_rng(4), temps_c=[25.0], samples_per_point=2)
    csvio.write_csv(one_temp, csvio.contract_columns(ds))
    code, _, err = _run(capsys, "refit", one_temp, "--model", "t24", "-o", tmp_path / "c.yaml")
    assert code != 0 and "K and kb" in err and "fit P12" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "c.yaml").exists()


def test_apply_needs_what_the_model_needs(t24_csv, tmp_path, capsys):
    path, _, _ = t24_csv
    cal_path = tmp_path / "cal.yaml"
    assert _run(capsys, "refit", path, "-o", cal_path)[0] == 0
    no_temp = tmp_path / "notemp.csv"
    no_temp.write_text("hx,hy,hz\n1,2,3\n")
    code, _, err = _run(capsys, "apply", cal_path, no_temp, "-o", tmp_path / "o.csv")
    assert code != 0 and "temperature" in err and not (tmp_path / "o.csv").exists()
    bogus = tmp_path / "bogus.yaml"
    bogus.write_text("model: t24\nparams: [1, 2\n")
    code, _, err = _run(capsys, "apply", bogus, path, "-o", tmp_path / "o.csv")
    assert code != 0 and "bogus.yaml" in err and "not valid YAML" in err


def test_scalar_refit_with_constant_norm_and_counts(tmp_path, capsys):
    ds, _ = synthetic.scalar_dataset(np.random.default_rng(5), n=600)
    counts = np.round(ds.h_nt / 100.0)  # 1000 counts per gauss = 100 nT per count
    path = tmp_path / "counts.csv"
    csvio.write_csv(path, {"mx": counts[:, 0], "my": counts[:, 1], "mz": counts[:, 2]})
    options = "--model scalar --raw-unit counts --counts-per-unit 1000/gauss --columns hx=mx,hy=my,hz=mz"
    code, out, err = _run(
        capsys, "refit", path, *options.split(), "--field-norm-nt", "50000", "-o", tmp_path / "s.json"
    )
    assert code == 0, err
    cal = calfile.load(tmp_path / "s.json")
    assert cal.stats["norm_spread_pct"] < 0.1 and "given constant 50000 nT" in cal.stats["field_norm"]


def test_apply_reuses_the_fitted_raw_unit_and_column_map(tmp_path, capsys):
    ds, truth = synthetic.scalar_dataset(np.random.default_rng(6), n=400)
    path = tmp_path / "gauss.csv"
    csvio.write_csv(
        path,
        {
            "t_s": np.arange(len(ds)) * 0.1,
            "mx": ds.h_nt[:, 0] / 1e5,
            "my": ds.h_nt[:, 1] / 1e5,
            "mz": ds.h_nt[:, 2] / 1e5,
        },
    )
    cal_path, out = tmp_path / "s.yaml", tmp_path / "out.csv"
    options = "--model scalar --raw-unit gauss --columns hx=mx,hy=my,hz=mz --field-norm-nt 50000"
    code, _, err = _run(capsys, "refit", path, *options.split(), "-o", cal_path)
    assert code == 0, err
    code, _, err = _run(capsys, "apply", cal_path, path, "-o", out)  # no unit or mapping given again
    assert code == 0, err
    result = csvio.read_csv(out, columns={"hx": "mx", "hy": "my", "hz": "mz"})
    norm = np.linalg.norm(np.column_stack([result.columns[c] for c in ("bx", "by", "bz")]), axis=1)
    assert abs(norm.mean() - 50000) < 5 and norm.std() < 15


def test_session_file_goes_to_the_store(tmp_path, capsys):
    session = tmp_path / "run.magrig"
    sqlite3.connect(session).execute("create table t (x)").connection.commit()
    code, _, err = _run(capsys, "refit", session, "--dut", "dut1", "-o", tmp_path / "c.yaml")
    assert code != 0 and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_refit_reads_a_real_session_file(tmp_path, capsys):
    from pathlib import Path

    from drivers.clock import SimClock
    from rig.config.loading import load_campaign
    from rig.schedules.compile import compile_plan
    from rig.session.rows import SampleRow
    from rig.session.writer import Session

    demo = Path(__file__).resolve().parents[3] / "configs" / "plans" / "demo.yaml"
    campaign = load_campaign(demo)
    points = compile_plan(campaign.plan, campaign.station)
    rng = np.random.default_rng(7)
    truth = synthetic.random_t24_params(rng)
    path = tmp_path / "run.magrig"
    with Session.create_for(path, campaign, points, clock=SimClock()) as session:
        for point in points:
            temp = point.setpoint_c + 0.1
            field = np.asarray(point.field_nt, float)
            m = truth["S"] + temp * truth["K"]
            h_true = np.linalg.solve(m, field - truth["b_nt"] - temp * truth["kb_nt_per_c"])
            rows = [
                SampleRow(
                    dut="dut1",
                    t=10.0 * point.index + i,
                    field_nt=tuple(h_true + rng.normal(0, 10, 3)),
                    ref_field_nt=tuple(field),
                    temp_c=temp,
                )
                for i in range(5)
            ]
            session.record_point(point.id, rows)
    cal_path = tmp_path / "cal.yaml"
    code, out, err = _run(capsys, "refit", path, "--dut", "dut1", "--model", "t24", "-o", cal_path)
    assert code == 0, err
    cal = calfile.load(cal_path)
    assert cal.source["kind"] == "session" and cal.source["rows_used"] == 5 * len(points)
    for name in ("S", "b_nt"):
        assert np.max(np.abs((cal.params[name] - truth[name]) / cal.std_errors[name])) < 4.5


def test_apply_warns_of_rows_beyond_the_calibrations_temperatures_and_directions(tmp_path, capsys):
    """Fitted on the upper half of the cube's 26 directions between -30 and 70 degC, the calibration is
    applied to the field straight down (90 deg from the nearest direction taken, which are 45 deg apart
    at most) and at 80 degC: each is counted, once, and the rows within both give no warning."""
    rng = np.random.default_rng(3)
    dirs = synthetic.coil_directions()
    fitted, truth = synthetic.t24_dataset(rng, directions=dirs[dirs[:, 2] >= 0], samples_per_point=3)
    fitted.group = None
    train, cal_path = tmp_path / "train.csv", tmp_path / "cal.yaml"
    csvio.write_csv(train, csvio.contract_columns(fitted))
    assert _run(capsys, "refit", train, "--model", "t24", "-o", cal_path)[0] == 0
    code, _, err = _run(capsys, "apply", cal_path, train, "-o", tmp_path / "same.csv")
    assert code == 0 and "warning" not in err
    up_and_down = np.array([[0, 0, 1.0], [0, 0, -1.0]])
    used, _ = synthetic.t24_dataset(rng, params=truth.params, directions=up_and_down, temps_c=(20.0, 80.0),
                                    samples_per_point=2)
    used.group = None
    beyond = tmp_path / "beyond.csv"
    csvio.write_csv(beyond, csvio.contract_columns(used))
    code, _, err = _run(capsys, "apply", cal_path, beyond, "-o", tmp_path / "out.csv")
    lines = err.strip().splitlines()
    assert code == 0 and len(lines) == 2 and all(line.startswith("warning: ") for line in lines)
    assert "4 rows outside the calibration's temperatures" in lines[0] and "80.0" in lines[0]
    assert "4 rows at field directions" in lines[1] and "(45 deg; up to 90 deg)" in lines[1]
