"""Figure functions (arrays -> Figure/PNG) and the self-contained HTML page."""

from __future__ import annotations

import base64
import re

import numpy as np

from rig.report import figures
from rig.report.html import Image, ItemList, Section, Table, images_in, render_html

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _data(n=600, seed=0):
    rng = np.random.default_rng(seed)
    temp = np.repeat([-20.0, 25.0, 60.0], n // 3)
    d = rng.normal(size=(n, 3)) * 50000
    return temp, d, d * 0.02 + 300, rng.normal(0, 20, (n, 3))


def test_residual_figure_has_units_and_one_row_per_axis():
    temp, _, before, after = _data()
    outliers = np.zeros(len(temp), bool)
    outliers[:3] = True
    after[:3] = 1e4
    fig = figures.residuals_vs_temperature(temp, before, after, ["x", "y", "z"], outliers)
    axes = fig.get_axes()
    assert len(axes) == 6
    assert axes[-1].get_xlabel() == "DUT temperature (°C)"
    assert all("(nT)" in ax.get_ylabel() for ax in axes)
    legend = [t.get_text() for t in axes[1].get_legend().get_texts()]
    assert any("outliers (3, 3 off-scale at the edge)" in t for t in legend)
    assert axes[1].get_ylim()[1] < 200  # the good samples are not squashed by the outliers
    # RMS in the legend is computed without the outliers
    want = np.sqrt(np.mean(after[~outliers, 0] ** 2))
    assert f"RMS {want:.1f} nT" in legend[0]
    assert figures.png_bytes(fig).startswith(PNG_MAGIC)


def test_residual_figure_without_temperature_uses_sample_index():
    _, _, before, after = _data(90)
    fig = figures.residuals_vs_temperature(None, before[:, :1], after[:, :1], ["|B|"])
    assert len(fig.get_axes()) == 2
    assert fig.get_axes()[-1].get_xlabel() == "sample index"


def test_histogram_range_ignores_a_few_outliers():
    rng = np.random.default_rng(1)
    after = rng.normal(0, 10, 5000)
    after[:3] = 1e5
    fig = figures.norm_error_histogram(rng.normal(500, 300, 5000), after)
    ax = fig.get_axes()[1]
    assert ax.get_xlim()[1] < 1000  # not stretched to the outliers
    assert "3 beyond the axis" in ax.get_legend().get_texts()[0].get_text()
    assert ax.get_xlabel() == "|B| error (nT)"


def test_direction_map_shows_coverage_gaps():
    rng = np.random.default_rng(2)
    d = rng.normal(size=(4000, 3))
    full = figures.direction_map(d, np.abs(rng.normal(0, 20, 4000)), gap_deg=35)
    assert full.get_axes()[0].get_title().startswith("coverage: 0 %")
    d[:, 2] = np.abs(d[:, 2])  # upper hemisphere only: the map below about -35 deg is a gap
    half = figures.direction_map(d, np.abs(rng.normal(0, 20, 4000)), gap_deg=35)
    share = int(re.search(r"coverage: (\d+) %", half.get_axes()[0].get_title()).group(1))
    assert 20 <= share <= 40
    assert half.get_axes()[0].get_ylabel() == "field elevation, reference axes (deg)"


def test_azimuth_elevation():
    az, el = figures.azimuth_elevation_deg(np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 2.0], [-1.0, 0, -1.0]]))
    np.testing.assert_allclose(az, [0, 90, 0, 180])
    np.testing.assert_allclose(el, [0, 0, 90, -45])


def test_model_comparison_marks_missing_values():
    nan = float("nan")
    fig = figures.model_comparison(
        ["t24", "p12", "scalar"],
        {"vector": [20, 300, nan], "|B|": [19, 290, 25]},
        {"vector": [21, 310, nan], "|B|": [20, 300, 26]},
    )
    vector, norm = fig.get_axes()[:2]
    texts = [t.get_text() for t in vector.texts]
    assert texts.count("n/a") == 2 and "310" in texts
    assert "n/a" not in [t.get_text() for t in norm.texts]
    assert vector.get_yscale() == "log" and norm.get_ylabel() == "|B| error RMS (nT)"


def test_html_is_self_contained_and_escaped():
    png = figures.png_bytes(figures.step_rms([0, 10], [500, 600], [20, 21]))
    sections = [
        Section(
            "Data <quality>", [ItemList(["step 3 <timeout>"], kind="warning"), ItemList([], empty_text="ok")]
        ),
        Section(
            "Figures", [Image(png, "steps & rms", "steps.png"), Table(["a", "b"], [["1", "<2>"]], "cap")]
        ),
    ]
    page = render_html("Report <x>", sections, subtitle="s")
    assert "&lt;quality&gt;" in page and "step 3 &lt;timeout&gt;" in page and "&lt;2&gt;" in page
    assert "<script" not in page and "http" not in page.replace("http-equiv", "")
    src = re.search(r'src="data:image/png;base64,([^"]+)"', page).group(1)
    assert base64.b64decode(src) == png
    assert [i.filename for i in images_in(sections)] == ["steps.png"]
    assert '<ul class="warning">' in page and "<p>ok</p>" in page
