"""The compiled CSV scanner: the same numbers as Python's float(), the same dataset as the columnar
reader, any block size, and a clean hand-over to that reader for files it does not take."""

import hashlib
import random

import numpy as np
import pytest

from calib.errors import DataError
from calib.io import csvfast, csvio

pytestmark = pytest.mark.skipif(csvfast._scanner() is None, reason="numba not available: no compiled scanner")


def _write(tmp_path, text, name="data.csv"):
    path = tmp_path / name
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return path


def _hard_numbers(n: int, seed: int = 0) -> list[str]:
    """Number spellings that exercise every rounding path: shortest reprs over many magnitudes, random
    bit patterns, long digit strings (more than 19 digits), exact halfway cases, the edges of float64."""
    rng = np.random.default_rng(seed)
    rand = random.Random(seed)
    texts = [repr(float(v)) for v in rng.normal(0, 1, n) * 10.0 ** rng.integers(-30, 30, n)]
    bits = rng.integers(0, 2**63, n, dtype=np.int64).view(np.float64)
    texts += [repr(float(v)) for v in bits if np.isfinite(v)]
    for _ in range(n):
        digits = "".join(rand.choice("0123456789") for _ in range(rand.randint(1, 25)))
        cut = rand.randint(0, len(digits))
        text = digits[:cut] + "." + digits[cut:] if cut < len(digits) else digits
        if rand.random() < 0.5:
            text += rand.choice("eE") + str(rand.randint(-330, 310))
        texts.append(rand.choice(["", "-", "+"]) + text)
    texts += [str(2**53 + 2 * k + 1) + suffix for k in range(200) for suffix in ("", "e-5", "0e-6")]
    texts += ["0", "-0", "0.0", "-0.000", "1e-320", "4.9e-324", "2.2250738585072014e-308",
              "1.7976931348623157e308", "1.7976931348623158e308", "9007199254740993", " 3.5 ", "\t-2",
              "5.", ".5", "1E5", "0.1000000000000000055511151231257827", "123456789012345678901234567890",
              "0." + "0" * 30 + "1"]
    return texts


def test_every_number_reads_as_python_float_reads_it(tmp_path):
    texts = _hard_numbers(20000)
    shifted = texts[7:] + texts[:7]
    path = _write(tmp_path, "a,b\n" + "".join(f"{x},{y}\n" for x, y in zip(texts, shifted, strict=True)))
    result = csvfast.read_numeric(path, ["a", "b"], ["a", "b"])
    assert result is not None, "a plain numeric file must take the fast path"
    table, sha256 = result
    for k, spelled in enumerate((texts, shifted)):
        expected = np.array([float(t) for t in spelled])
        same = (table[:, k] == expected) & (np.signbit(table[:, k]) == np.signbit(expected))
        wrong = np.flatnonzero(~same)
        assert wrong.size == 0, [(spelled[i], table[i, k], expected[i]) for i in wrong[:5]]
    assert sha256 == hashlib.sha256(path.read_bytes()).hexdigest()


def _numeric_file(tmp_path, rows: int = 3000, crlf: bool = False):
    rng = np.random.default_rng(1)
    values = rng.normal(0, 3e4, (rows, 5))
    end = "\r\n" if crlf else "\n"
    lines = ["t_s,hx,hy,hz,temp"]
    for i, row in enumerate(values.tolist()):
        cells = [repr(v) if i % 3 else f"{v:.3f}" for v in row]
        if i % 97 == 5:
            cells[2] = f"  {cells[2]} "  # spaces around a number
        lines.append(",".join(cells))
        if i % 500 == 7:
            lines.append("")  # blank lines are skipped
    return _write(tmp_path, end.join(lines) + end)


@pytest.mark.parametrize("crlf", [False, True])
def test_the_scanner_and_the_columnar_reader_give_the_same_dataset(tmp_path, monkeypatch, crlf):
    path = _numeric_file(tmp_path, crlf=crlf)
    scanned = _scanner_asked(monkeypatch)
    fast = csvio.read_csv(path)
    assert scanned == [True]  # the scanner read it
    monkeypatch.setattr(csvfast, "_SCANNER", [None])  # as without numba
    columnar = csvio.read_csv(path)
    assert len(fast) == len(columnar) == 3000
    for name in ("t_s", "hx", "hy", "hz", "temp"):
        np.testing.assert_array_equal(fast.columns[name], columnar.columns[name])
    np.testing.assert_array_equal(fast.h_nt, columnar.h_nt)
    assert fast.source["sha256"] == columnar.source["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()


def _scanner_asked(monkeypatch) -> list[bool]:
    """Files of any size handed to the scanner; the list records whether each read took it."""
    monkeypatch.setattr(csvfast, "COMPILED_BREAK_EVEN_BYTES", 0)
    read_numeric, taken = csvfast.read_numeric, []

    def recording(*args):
        result = read_numeric(*args)
        taken.append(result is not None)
        return result

    monkeypatch.setattr(csvfast, "read_numeric", recording)
    return taken


def test_a_file_below_the_break_even_is_read_without_loading_the_scanner(tmp_path, monkeypatch):
    path = _numeric_file(tmp_path, rows=200)
    assert path.stat().st_size < csvfast.COMPILED_BREAK_EVEN_BYTES

    def refuse(*args):
        raise AssertionError("the scanner was asked for a small file")

    monkeypatch.setattr(csvfast, "read_numeric", refuse)
    assert len(csvio.read_csv(path)) == 200


def test_blocks_and_pieces_of_any_size_give_the_same_columns(tmp_path, monkeypatch):
    path = _numeric_file(tmp_path, rows=2000)
    whole = csvfast.read_numeric(path, ["t_s", "hx", "hy", "hz", "temp"], ["hx", "hy", "hz"])
    # blocks smaller than one line (the buffer grows), a few lines, many lines; few float() slots
    monkeypatch.setattr(csvfast, "SLOW_CELLS", 1)
    for block in (16, 300, 5000):
        monkeypatch.setattr(csvfast, "BLOCK_BYTES", block)
        parts = csvfast.read_numeric(path, ["t_s", "hx", "hy", "hz", "temp"], ["hx", "hy", "hz"])
        assert parts is not None
        np.testing.assert_array_equal(parts[0], whole[0])
        assert parts[1] == whole[1]


def test_many_cells_for_float_and_lines_shorter_than_the_first(tmp_path, monkeypatch):
    """Cells the scanner hands to float() beyond its list, and an output sized from a long first line."""
    long_cells = ["0.1000000000000000055511151231257827" + str(i) for i in range(50)]
    lines = ["hx,hy,hz", "1.00000000000000000000000000000000001,2,3"] + [f"{c},1,-{c}" for c in long_cells]
    path = _write(tmp_path, "\n".join(lines) + "\n")
    monkeypatch.setattr(csvfast, "SLOW_CELLS", 3)
    table, _ = csvfast.read_numeric(path, ["hx", "hy", "hz"], ["hx", "hy", "hz"])
    np.testing.assert_array_equal(table[:, 0], [float(line.split(",")[0]) for line in lines[1:]])
    np.testing.assert_array_equal(table[:, 2], [float(line.split(",")[2]) for line in lines[1:]])


@pytest.mark.parametrize(
    "text",
    [
        'hx,hy,hz\n1,2,"3"\n',  # quoted cell
        "hx,hy,hz,note\n1,2,3,ok\n",  # text column, seen on the first line
        "hx,hy,hz,note\n1,2,3,4\n1,2,3,late text\n",  # text column, seen later
        "hx,hy,hz,note\n1,2,3,4\n1,2,3,\"a,b\"\n",  # quoting hides a separator
        "hx,hy,hz\n1,2,3\n1,2,3,4\n",  # one cell too many
        "hx,hy,hz\n1,2,3\n1,2\n",  # one cell too few
        "hx,hy,hz\n1,2,3\n1,2,nan\n",  # not a finite number
        "hx,hy,hz\n1,2,3\n1,2,1_000\n",  # Python reads it, the scanner does not
    ],
)
def test_files_not_in_its_shape_are_left_to_the_columnar_reader(tmp_path, text):
    path = _write(tmp_path, text)
    header = text.split("\n", 1)[0].split(",")
    assert csvfast.read_numeric(path, header, header) is None


def test_the_reader_still_names_line_and_column_of_a_bad_cell_deep_in_a_file(tmp_path, monkeypatch):
    rows = ["hx,hy,hz"] + [f"{i}.5,{i + 1},{i + 2}" for i in range(5000)]
    rows[4321] = "1,2,3x"
    monkeypatch.setattr(csvfast, "BLOCK_BYTES", 2048)
    scanned = _scanner_asked(monkeypatch)
    with pytest.raises(DataError, match="line 4322, column 'hz': '3x' is not a number"):
        csvio.read_csv(_write(tmp_path, "\n".join(rows) + "\n"))
    assert scanned == [False]  # the scanner handed the file over


def test_a_header_without_data_rows_is_refused(tmp_path):
    with pytest.raises(DataError, match="no data rows"):
        csvio.read_csv(_write(tmp_path, "hx,hy,hz\n\n"))
