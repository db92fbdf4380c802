"""The columnar CSV reader: blocks, carried columns, and one clear line for every malformed file."""

import numpy as np
import pytest

from calib.errors import DataError
from calib.io import csvio


def _write(tmp_path, text, name="data.csv"):
    path = tmp_path / name
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


def test_many_small_blocks_give_the_same_dataset_as_one(tmp_path, monkeypatch):
    rng = np.random.default_rng(3)
    values = rng.normal(0, 3e4, (3000, 7))
    lines = ["hx,hy,hz,temp,bx,by,bz,point"] + [
        ",".join(repr(v) for v in row) + f",P{i % 7}" for i, row in enumerate(values.tolist())
    ]
    path = _write(tmp_path, "\n".join(lines) + "\n")
    one = csvio.read_csv(path)
    monkeypatch.setattr(csvio, "BLOCK_BYTES", 4096)  # ~30 blocks
    many = csvio.read_csv(path)
    for ds in (one, many):
        np.testing.assert_array_equal(ds.h_nt, values[:, :3])  # shortest repr: exact round trip
        np.testing.assert_array_equal(ds.temp_c, values[:, 3])
        np.testing.assert_array_equal(ds.ref_nt, values[:, 4:])
        assert ds.columns["point"].dtype == object and ds.columns["point"][8] == "P1"
    assert one.source["sha256"] == many.source["sha256"]
    import hashlib

    assert one.source["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_fit_reads_only_the_contract_columns(tmp_path):
    path = _write(tmp_path, "note,hx,hy,hz,t_s\nfirst,1,2,3,0.5\nsecond,4,5,6,1.0\n")
    full = csvio.read_csv(path)
    lean = csvio.read_csv(path, extra_columns=False)
    assert list(full.columns) == ["note", "hx", "hy", "hz", "t_s"]
    assert list(lean.columns) == ["hx", "hy", "hz"]
    np.testing.assert_array_equal(lean.h_nt, full.h_nt)
    np.testing.assert_array_equal(full.columns["t_s"], [0.5, 1.0])


def test_blank_lines_bom_and_integer_cells_are_read(tmp_path):
    path = _write(tmp_path, "\ufeffhx,hy,hz,group\n1,2,3,1\n\n4,5,6,2\n")
    ds = csvio.read_csv(path)
    np.testing.assert_array_equal(ds.h_nt, [[1, 2, 3], [4, 5, 6]])
    assert ds.h_nt.dtype == float and list(ds.group) == [1.0, 2.0]


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("hx,hy,hz\n1,2,3\n4,NA,6\n", "line 3, column 'hy': 'NA' is not a number"),
        ("hx,hy,hz\n1,2,3\n4,,6\n", "line 3, column 'hy': '' is not a number"),
        ("hx,hy,hz,bx\n1,2,3,4\n4,5,6\n", "line 3: 3 cells, the header has 4"),
        ("hx,hy,hz\n1,2,3\n1,2,3,4\n", "line 3: 4 cells, the header has 3"),
        (b"hx,hy,hz,note\n1,2,3,ok\n4,5,6,\xff\n", "line 3: not UTF-8 text"),
        ("hx,hy,hz,temp\n1,2,3,20\n4,5,6,-inf\n", "line 3\\), column 'temp': -inf is not finite"),
        ("hx,hx,hz\n1,2,3\n", "line 1: column 'hx' appears twice"),
    ],
)
def test_malformed_files_name_file_line_and_column(tmp_path, text, expected):
    path = _write(tmp_path, text)
    with pytest.raises(DataError, match=expected) as info:
        csvio.read_csv(path)
    assert str(path) in str(info.value)


def test_an_error_deep_in_a_later_block_names_its_line(tmp_path, monkeypatch):
    rows = ["hx,hy,hz"] + [f"{i},{i + 1},{i + 2}" for i in range(5000)]
    rows[4321] = "1,2,x3"
    monkeypatch.setattr(csvio, "BLOCK_BYTES", 2048)
    with pytest.raises(DataError, match="line 4322, column 'hz': 'x3' is not a number"):
        csvio.read_csv(_write(tmp_path, "\n".join(rows) + "\n"))
