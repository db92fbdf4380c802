"""CLI: rig refit (fit a calibration to a CSV or session file), rig apply (calibrate a CSV)."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from calib.models.registry import MODELS, REGISTRY
from rig import __version__
from rig.session.schema import looks_like_session

MODEL_CHOICE = click.Choice(MODELS)


def _unit_options(f):
    f = click.option(
        "--columns",
        "column_map",
        metavar="OURS=THEIRS,...",
        help="Map CSV columns, e.g. hx=mx_gauss,hy=my_gauss,hz=mz_gauss.",
    )(f)
    f = click.option(
        "--counts-per-unit",
        metavar="X[/UNIT]",
        help="With --raw-unit counts: counts per UNIT (default per gauss), e.g. 1090/gauss.",
    )(f)
    return click.option(
        "--raw-unit",
        metavar="nT|uT|mT|gauss|counts",
        default=None,
        help="Unit of hx,hy,hz in the input (refit default nT; apply default: as fitted).",
    )(f)


def load_dataset(path: str, *, dut: str | None, raw_unit: str, counts_per_unit, column_map: str | None,
                 extra_columns: bool = True):
    """A Dataset from a session file (by its name or content; via rig.session.reader) or a CSV file
    (extra_columns: keep the columns outside the CSV contract; a fit does not need them)."""
    from calib.io import csvio
    from rig.core.errors import DataError

    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: no such file")
    if looks_like_session(p):
        from rig.session.reader import read_dataset

        return read_dataset(p, dut)
    if dut is not None:
        raise DataError(f"{p}: --dut applies to session files; this is a CSV file")
    ds = csvio.read_csv(
        p,
        raw_unit=raw_unit,
        counts_per_unit=counts_per_unit,
        columns=csvio.parse_column_map(column_map),
        extra_columns=extra_columns,
    )
    ds.source["column_map"] = column_map or ""
    ds.source["counts_per_unit"] = "" if counts_per_unit is None else str(counts_per_unit)
    return ds


@click.command("refit")
@click.argument("data", type=click.Path(dir_okay=False))
@click.option("--model", type=MODEL_CHOICE,
              help="Calibration model (default: a session's judged model, the plan's; a CSV's t24).")
@click.option("--robust/--no-robust", default=None,
              help="Huber reweighting; outliers are flagged and counted (default: a session's plan's "
              "fit.robust; a CSV's off).")
@click.option("--dut", metavar="NAME", help="DUT to fit, when DATA is a session file.")
@_unit_options
@click.option("--field-norm-nt", type=float, help="Scalar model: the known constant |B| in nT.")
@click.option(
    "--balance-orientations/--no-balance-orientations",
    default=None,
    help="Scalar model: weight samples so over-visited orientations do not dominate "
    "(default: chosen by cross-validation inside the data when the coverage is uneven).",
)
@click.option("--temp-ref-c", type=float,
              help="Where the solve centres the temperature (degC): t24's solve_centre_c, internal (the "
              "field does not change); a scalar fit's tau_0_c, which its equation subtracts.")
@click.option("--lag/--no-lag", default=True, show_default=True,
              help="Ramp session: estimate each DUT's thermal lag and fit its element temperature.")
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(dir_okay=False),
    help="Calibration file to write (.yaml, or .json).",
)
def refit(
    data,
    model,
    robust,
    dut,
    raw_unit,
    counts_per_unit,
    column_map,
    field_norm_nt,
    balance_orientations,
    temp_ref_c,
    lag,
    output,
):
    """Fit a calibration to DATA (a CSV file or a session file) and write it to OUTPUT. A session is
    fitted exactly as its run fitted it (rig/analysis/sessionfit.py): references with the run's best
    ambient, a moving schedule's lag corrected, its plan's options unless given here."""
    import calib
    from calib.io import calfile

    ds = load_dataset(
        data,
        dut=dut,
        raw_unit=raw_unit or "nT",
        counts_per_unit=counts_per_unit,
        column_map=column_map,
        extra_columns=False,
    )
    session = ds.source.get("kind") == "session"
    fitter = None
    if session:
        from rig.analysis.sessionfit import SessionFitter
        from rig.session.reader import SessionReader

        with SessionReader(data) as reader:
            fitter = SessionFitter.of(reader)
    model = model or (fitter.plan.judged_model if fitter is not None and fitter.plan is not None else "t24")
    given = {"field_norm_nt": field_norm_nt, "balance_orientations": balance_orientations}
    unused = [n for n, value in given.items() if value is not None and n not in REGISTRY[model].options]
    if unused:
        takers = [m for m, spec in REGISTRY.items() if set(unused) <= spec.options]
        raise click.UsageError(f"{', '.join('--' + n.replace('_', '-') for n in unused)} apply to "
                               f"--model {' or '.join(takers)} only")
    options = {"temp_ref_c": temp_ref_c, **given}
    if fitter is not None:
        prepared = fitter.prepare(ds, lag=lag)
        cal = fitter.calibrate(prepared, model, robust=robust, software_version=__version__, **options)
        if prepared.lag is not None:
            click.echo(prepared.lag["message"])
    else:
        from calib.uncertainty.montecarlo import statistical_only
        from rig.analysis.measurand import state_csv

        cal = calib.fit(ds, model, robust=bool(robust), software_version=__version__, **options)
        cal.uncertainty = statistical_only(ds, cal)
        state_csv(cal, ds)
    calfile.save(cal, output)
    print_summary(cal)
    click.echo(f"wrote {output}")


@click.command("apply")
@click.argument("calibration", type=click.Path(dir_okay=False))
@click.argument("data", type=click.Path(dir_okay=False))
@_unit_options
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), help="CSV file to write.")
@click.option("--uncertainty", "with_uncertainty", is_flag=True,
              help="Also write each row's expanded uncertainty from the calibration's covariance: "
              "u_bx,u_by,u_bz (k u per axis, nT), u_b (radius holding 95 % of the 3-D error, nT) and "
              "u_norm (interval holding 95 % of the error of |B|, nT: what a scalar fit answers for).")
def apply_cmd(calibration, data, raw_unit, counts_per_unit, column_map, output, with_uncertainty):
    """Calibrate every row of DATA: writes its columns plus bx,by,bz (calibrated field, nT).

    Reference columns bx,by,bz already in DATA are kept as ref_bx,ref_by,ref_bz. The raw unit and
    column mapping default to those the calibration was fitted with.
    """
    from calib.io import calfile, csvio
    from rig.core.errors import DataError

    cal = calfile.load(calibration)
    if raw_unit is None:
        raw_unit = cal.source.get("raw_unit", "nT")
        counts_per_unit = counts_per_unit or cal.source.get("counts_per_unit") or None
    column_map = column_map if column_map is not None else cal.source.get("column_map") or None
    ds = load_dataset(
        data, dut=None, raw_unit=raw_unit, counts_per_unit=counts_per_unit, column_map=column_map
    )
    field = cal.apply(ds.h_nt, ds.temp_c)
    out = {}
    for name, values in ds.columns.items():
        new = f"ref_{name}" if name in csvio.REF_COLUMNS else name
        if new in out or new in csvio.REF_COLUMNS:
            raise DataError(f"{data}: column {new!r} would appear twice in the output")
        out[new] = values
    for i, name in enumerate(csvio.REF_COLUMNS):
        out[name] = field[:, i]
    note = ""
    if with_uncertainty:
        note = _uncertainty_columns(cal, ds, out, calibration)
    csvio.write_csv(output, out)
    click.echo(f"wrote {output}: {len(ds)} rows calibrated with {cal.model} ({calibration}){note}; "
               + equation_line(cal))
    for line in [*beyond_calibration(cal, ds.temp_c, field), *magnitude_guards(cal, ds.h_nt, raw_unit)]:
        click.echo(f"warning: {line}", err=True)
    for line in missing_lines(cal, calibration):
        click.echo(line, err=True)


def missing_lines(cal, where: str) -> list[str]:
    """One line for each thing the calibration file does not state of its measurand (files before format
    version 3 state none of it: calib.Calibration.missing_measurand)."""
    return [f"note: {where} (format version {cal.format_version}) does not state {what}"
            for what in cal.missing_measurand()]


def magnitude_guards(cal, h_nt, raw_unit: str | None) -> list[str]:
    """Rows whose |h| lies more than 10 % outside the field magnitudes the calibration was made at, and
    input whose magnitudes suggest another raw unit (calib/stats/magnitudes.py); each one line."""
    from calib.calibration import MAGNITUDES_KEY
    from calib.stats.magnitudes import MARGIN, outside_magnitudes, unit_suspected

    span = (cal.stats.get(MAGNITUDES_KEY) or {}).get("h")
    if span is None or not len(h_nt):
        return []
    out = []
    outside = outside_magnitudes(span, h_nt)
    if outside.any():
        norm = np.linalg.norm(h_nt[outside], axis=1)
        out.append(f"{int(outside.sum())} of {len(h_nt)} rows with |h| outside the calibrated field "
                   f"magnitudes ({span[0]:.0f} .. {span[1]:.0f} nT) by more than {MARGIN:.0%} (|h| "
                   f"{norm.min():.4g} .. {norm.max():.4g} nT; first row {int(np.flatnonzero(outside)[0])}): "
                   "extrapolated")
    suspect = unit_suspected(span, h_nt)
    if suspect:
        out.append(f"raw unit {raw_unit or 'nT'}: {suspect} (state it with --raw-unit)")
    return out


def beyond_calibration(cal, temp_c, field_nt) -> list[str]:
    """What of the rows lies beyond the calibration's own data, where its field and its uncertainty are
    extrapolated: temperatures outside its range, field directions farther from those it took than they
    are from each other (calib/stats/directions.py)."""
    from calib.stats.directions import beyond_taken

    out = []
    span = cal.stats.get("temperature_range_c")
    if span is not None and temp_c is not None:
        temps = np.asarray(temp_c, float)
        outside = (temps < span[0]) | (temps > span[1])
        if outside.any():
            out.append(f"{int(outside.sum())} rows outside the calibration's temperatures ({span[0]:.1f} "
                       f".. {span[1]:.1f} degC; they reach {temps.min():.1f} .. {temps.max():.1f}): "
                       "extrapolated")
    taken = cal.stats.get("field_directions")
    if taken:
        far, angles, apart = beyond_taken(taken, field_nt)
        if far.any():
            out.append(f"{int(far.sum())} rows at field directions farther from any the calibration took "
                       f"than those are apart ({apart:.0f} deg; up to {angles.max():.0f} deg): extrapolated"
                       + (", and a scalar fit has no reference direction to hold it there"
                          if cal.model == "scalar" else ""))
    return out


def equation_line(cal) -> str:
    """The equation the calibration applies and what tau is, as its file states them."""
    keys = cal.equation_keys()
    if keys["tau"] == "not_used":
        return f"equation: {keys['equation']} (no temperature)"
    tau_0 = f"; tau_0_c = {keys['tau_0_c']:g} degC" if "tau_0_c" in keys else ""
    return (f"equation: {keys['equation']}; tau = the temp column in degC as it is "
            f"(tau: {keys['tau']}){tau_0}")


UNCERTAINTY_COLUMNS = ("u_bx", "u_by", "u_bz", "u_b", "u_norm")


def _uncertainty_columns(cal, ds, out: dict, calibration: str) -> str:
    """Each row's expanded uncertainty (calib/uncertainty/fielderror.py) into `out`; what the user should
    know."""
    from calib.uncertainty.fielderror import expanded_at, expanded_norm_at, parameter_covariance
    from rig.core.errors import DataError

    if cal.uncertainty is None:
        raise DataError(f"{calibration}: states no uncertainty: --uncertainty needs a calibration with a "
                        "budget (rig refit of a session writes one)")
    for name in UNCERTAINTY_COLUMNS:
        if name in out:
            raise DataError(f"{calibration}: column {name!r} is already in the data")
    axes, radius = expanded_at(cal, ds.h_nt, ds.temp_c)
    for i, name in enumerate(UNCERTAINTY_COLUMNS[:3]):
        out[name] = axes[:, i]
    out[UNCERTAINTY_COLUMNS[3]] = radius
    out[UNCERTAINTY_COLUMNS[4]] = expanded_norm_at(cal, ds.h_nt, ds.temp_c)
    _, correlated = parameter_covariance(cal)
    k = float(cal.uncertainty["coverage_factor"])
    return (f"; expanded uncertainty (k = {k:g}) per row" + ("" if correlated else
            " from each parameter's own uncertainty: the file has no covariance, correlations are lost"))


def _fmt_with_error(value: float, err: float) -> str:
    return f"{value:.6g} ± {err:.2g}"


def print_summary(cal) -> None:
    """Parameters with standard errors, residual RMS before/after, per axis and per temperature step."""
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    from rig.analysis.measurand import reference_chain_words

    console = Console(highlight=False)
    st = cal.stats
    console.print(f"[bold]{cal.model}[/bold] fit of {st.get('n_used')} of {st.get('n')} samples")
    console.print(equation_line(cal), markup=False)
    console.print(reference_chain_words(cal.reference_chain), markup=False)
    title = escape("parameters ± std errors, named as the file names them: S[row][column], zero-based, "
                   "row = output axis of B")
    params = Table("parameter", *(escape(f"[{i}] {axis}") for i, axis in enumerate("xyz")), title=title)
    for name, value in cal.params.items():
        value = np.atleast_2d(value)
        err = np.atleast_2d(cal.std_errors[name])
        for i, (row, erow) in enumerate(zip(value, err, strict=True)):
            label = name if value.shape[0] == 1 else f"{name}[{i}][column]"
            params.add_row(escape(label), *(_fmt_with_error(v, e) for v, e in zip(row, erow, strict=True)))
    console.print(params)
    fit = Table("rows", "n", "RMS before (nT)", "RMS after (nT)", title="residuals")
    fit.add_row("all used", str(st.get("n_used")), f"{st['rms_before_nt']:.4g}", f"{st['rms_after_nt']:.4g}")
    for axis, entry in st.get("per_axis", {}).items():
        fit.add_row(
            f"axis {axis}",
            "",
            f"{entry.get('rms_before_nt', float('nan')):.4g}",
            f"{entry['rms_after_nt']:.4g}",
        )
    for label, entry in st.get("per_group", {}).items():
        temp = f" ({round(entry['temp_c'], 1) + 0.0:.1f} degC)" if "temp_c" in entry else ""
        fit.add_row(
            f"step {label}{temp}",
            str(entry["n"]),
            f"{entry['rms_before_nt']:.4g}",
            f"{entry['rms_after_nt']:.4g}",
        )
    console.print(fit)
    if "norm_spread_pct" in st:
        console.print(
            f"|B| spread after calibration: {st['norm_spread_pct']:.3f} % (std/mean); "
            f"field norm: {st.get('field_norm')}"
        )
    if "validation" in st:
        v = st["validation"]
        means = ", ".join(f"{name} {pct:.3f} %" for name, pct in v.get("mean_pct", {}).items())
        console.print(f"variant: {v['chosen']}, chosen by {v['method']}" + (f" (held-out |B| error: {means})"
                                                                            if means else ""))
    if st.get("robust"):
        console.print(
            f"robust: {st['n_outliers']} rows flagged as outliers and left out of the fit"
            + (f" (first rows: {st['outlier_rows_first']})" if st.get("outlier_rows_first") else "")
        )
    for warning in st.get("warnings", []):
        console.print(f"[yellow]warning:[/yellow] {warning}")


def register(group: click.Group) -> None:
    """Add this module's commands to the `rig` group."""
    group.add_command(refit)
    group.add_command(apply_cmd, name="apply")
