"""Commands on a finished campaign: ``fit``, ``export``, ``plot`` and ``report``."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from gonio.cli.common import Out as _Out
from gonio.cli.common import UsageError
from gonio.cli.common import lock_holder as _lock_holder
from gonio.cli.common import not_empty as _not_empty
from gonio.cli.common import writable_out as _writable_out


def cmd_fit(args) -> int:
    """Fit a model to a finished campaign; the MATERIAL string on stdout, the JSON in --out."""
    from gonio.dataset import BRDF_NAME
    from gonio.fit import fit, parse_channels, parse_model
    from gonio.jit import using_backend

    source = Path(args.dir)
    if not source.exists():
        raise UsageError(f"{source}: no such campaign folder or {BRDF_NAME} file")
    if source.is_dir() and not (source / BRDF_NAME).is_file() and _holds_many(source):
        return _fit_many(args, source)
    if args.workers is not None or args.scheduler is not None:
        raise UsageError("--workers/--scheduler: for a batch store or a folder of campaigns; one campaign "
                         "is fitted here")
    if source.is_dir() and not (source / BRDF_NAME).is_file():
        raise UsageError(f"{source}: not a finished campaign (no {BRDF_NAME}; it is written once every "
                         "step is measured: finish the campaign with the command that started it)")
    out = _writable_out(args.out, force=args.force) if args.out is not None else None
    # a bad --channels or MODEL is reported, naming its flag, before any data is read
    try:
        channels = parse_channels(args.channels)
    except ValueError as err:
        raise UsageError(f"--channels: {str(err).removeprefix('channels: ')}") from None
    try:
        parse_model(args.model, channels)
    except ValueError as err:
        raise UsageError(f"--model: {err}") from None
    if args.starts < 1:
        raise UsageError(f"--starts: must be an integer >= 1, got {args.starts}")
    with using_backend(args.backend):
        result = fit(source, args.model, channels=args.channels, loss=args.loss, starts=args.starts)
    if out is not None:
        tmp = out.with_name(out.name + ".partial")
        tmp.write_text(json.dumps(result.to_json(), indent=2) + "\n")
        tmp.replace(out)
    print(result.material)
    if not args.quiet:
        res = result.residual
        for name, v in result.parameters.items():
            flag = "  (at bound)" if v["at_bound"] else ""
            print(f"  {name} = {v['value']:.6g} ± {v['stddev']:.2g}{flag}", file=sys.stderr)
        structure = (f"structure {res['structure']:.2f}" if np.isfinite(res["structure"]) else
                     "structure not judged (no two residuals share a (θh, θd) bin: too few samples)")
        print(f"  loss ({result.loss}) {res['loss']:.6g} over {res['residuals']} residuals, "
              f"{res['dof']} degrees of freedom; per dof {res['chi2_reduced']:.3g}; relative "
              f"{res['rms_relative']:.3g}; {structure}"
              f"{'; MISFIT: the model leaves a structured residual' if res['misfit'] else ''}",
              file=sys.stderr)
        print("  model averaged over the cones the readings integrate: " + result.aperture.describe()
              if result.aperture is not None else "  model evaluated at the measured directions: the source "
              "and detector cones the readings integrate are not known (recorded in a simulated campaign's "
              "brdf.h5), so their smoothing of a sharp lobe is not modelled", file=sys.stderr)
        if result.loss == "chi2":   # the only loss whose uncertainties take shared errors in
            print(f"  errors the samples share: those of {res['shared_errors']} dark and white-reference "
                  "readings" if res["shared_errors"] else "  samples taken as independent: the errors "
                  "they share through the dark and white-reference readings are left out (found only in a "
                  "campaign folder whose journal calibrates to these values)",
                  file=sys.stderr)
    return 0


def _holds_many(folder: Path) -> bool:
    """A batch store, or a folder with finished campaigns in it."""
    from gonio.dataset import BRDF_NAME

    return (folder / ".zgroup").is_file() or any((p / BRDF_NAME).is_file() for p in folder.iterdir())


def _fit_many(args, source: Path) -> int:
    """``gonio fit STORE.zarr|FOLDER``: every material or campaign on the cluster, one table."""
    from gonio.batch.cluster import disconnect
    from gonio.batch.fit import FitJob, fit_many, sources, table_csv
    from gonio.cli.batch import connected
    from gonio.fit import parse_channels, parse_model

    out = _writable_out(args.out, force=args.force) if args.out is not None else None
    channels = parse_channels(args.channels)
    parse_model(args.model, channels)  # a bad MODEL is reported before any data is read
    if args.starts < 1:
        raise UsageError(f"--starts: must be an integer >= 1, got {args.starts}")
    kind, items = sources(source)
    if args.scheduler is None:
        from gonio.batch.cluster import start_fork_server

        start_fork_server()         # the local workers' imports, while this process imports Dask
    say = _Out(args.quiet)
    noun = "material" if kind == "store" else "campaign"
    client, cluster, threads = connected(args, say, f"fitting {args.model} to {len(items)} {noun}"
                                         f"{'s' * (len(items) != 1)}")
    try:
        def said(k, r):
            say(f"{r.status}: {r.source}" + (f": {r.error}" if r.error else ""))

        job = FitJob(args.model, args.channels, args.loss, args.starts)
        rows = fit_many(kind, items, job, client, threads, on_row=None if args.quiet else said)
    finally:
        disconnect(client, cluster)
    text = table_csv(rows)
    if out is None:
        sys.stdout.write(text)
    else:
        tmp = out.with_name(out.name + ".partial")
        tmp.write_text(text)
        tmp.replace(out)
    counts = {s: sum(r.status == s for r in rows) for s in ("ok", "misfit", "failed", "missing")}
    say(", ".join(f"{n} {s}" for s, n in counts.items()) + (f"; the table in {out}" if out else ""))
    return 1 if counts["failed"] else 0


# -- gonio export ---------------------------------------------------------------------------------
def export_formats(text: str | None) -> list[str]:
    if text is None:  # no --export: the exporters are not imported
        return []
    from gonio.export import parse_formats

    return parse_formats(text)


def write_exports(folder: Path, formats: list[str], out: _Out) -> None:
    """``gonio simulate --export``: each format under its unambiguous name in the campaign folder."""
    if not formats:  # no --export: the exporters are not imported
        return
    from gonio.export import export
    from gonio.registries import EXPORT_FORMATS

    for fmt in formats:
        out(f"export {export(folder, fmt, folder / EXPORT_FORMATS[fmt].extra['file_name'])}")


def finished_campaign(folder: Path) -> Path:
    """The ``brdf.h5`` of a finished campaign folder; a UsageError for anything else (no folder, not a
    campaign, still running, incomplete, brdf.h5 missing)."""
    from gonio.campaign import LOCK_NAME
    from gonio.dataset import BRDF_NAME
    from gonio.store import JOURNAL_NAME, Journal

    if not folder.is_dir():
        raise UsageError(f"{folder}: no such campaign folder")
    if not (folder / JOURNAL_NAME).is_file():
        raise UsageError(f"{folder}: not a campaign folder (no {JOURNAL_NAME})")
    pid = _lock_holder(folder)
    if pid is not None:
        raise UsageError(f"{folder}: the campaign is still running (pid {pid} holds {LOCK_NAME}); use it "
                         "once it has finished")
    j = Journal.open(folder / JOURNAL_NAME, readonly=True)
    try:
        done, total = j.done_count(), j.step_count()
    finally:
        j.close()
    if done < total:
        raise UsageError(f"{folder}: the campaign is incomplete ({done}/{total} steps measured); finish it "
                         "with the command that started it (it resumes), then use it")
    if not (folder / BRDF_NAME).is_file():
        raise UsageError(f"{folder}: every step is measured but {BRDF_NAME} is missing; run the command that "
                         "started the campaign again to write it")
    return folder / BRDF_NAME


def cmd_export(args) -> int:
    """Export a finished campaign; the report (cells from data, interpolated, empty) on stdout."""
    from gonio.export import export, parse_formats
    from gonio.registries import EXPORT_FORMATS

    fmt = parse_formats(args.format, "--format")
    if len(fmt) != 1:
        raise UsageError(f"--format: one format per export, got {args.format!r}")
    source = finished_campaign(Path(args.dir))
    out = _writable_out(args.out, folder=EXPORT_FORMATS[fmt[0]].extra.get("folder", False), force=args.force)
    report = export(source, fmt[0], out)
    print(report)
    for note in report.notes:
        print(f"  {note}")
    return 0


# -- gonio plot -----------------------------------------------------------------------------------
def cmd_plot(args) -> int:
    """Draw a finished campaign; the file written (and any caveat) on stdout."""
    from gonio.plot import SUFFIXES, plot
    from gonio.registries import PLOT_KINDS

    _not_empty(args.out)
    if args.kind not in PLOT_KINDS:
        raise UsageError(f"--kind: {args.kind!r} is unknown; allowed: {', '.join(PLOT_KINDS.names())}")
    if Path(args.out).suffix.lower() not in SUFFIXES:
        raise UsageError(f"--out: {args.out} must end in {', '.join(SUFFIXES)} (the suffix picks the format)")
    if not (np.isfinite(args.theta_i) and 0.0 <= args.theta_i < 90.0):
        raise UsageError(f"--theta-i: must be in [0, 90) degrees, got {args.theta_i}")
    if not np.isfinite(args.phi_i):
        raise UsageError(f"--phi-i: must be a finite number of degrees, got {args.phi_i}")
    source = finished_campaign(Path(args.dir))
    out = _writable_out(args.out, force=args.force)
    print(plot(source.parent, args.kind, out, theta_i_deg=args.theta_i, phi_i_deg=args.phi_i))
    return 0


# -- gonio report ---------------------------------------------------------------------------------
def cmd_report(args) -> int:
    """Write the HTML report of a finished campaign; the page's path and its verdict lines on stdout."""
    from gonio.report import SUFFIXES, parse_models, report
    from gonio.report.html import LEVELS

    out = Path(_not_empty(args.out))
    if out.is_dir():
        raise UsageError(f"--out: {out} is a folder; give a file name ending in .html")
    if out.suffix.lower() not in SUFFIXES:
        raise UsageError(f"--out: {out} must end in .html (the report is one self-contained HTML page)")
    models = parse_models(args.models)  # a bad MODEL is reported before any data is read
    source = finished_campaign(Path(args.dir))
    out = _writable_out(args.out, force=args.force)
    rep = report(source.parent, out, models)
    print(f"report: {out}")
    for level, topic, text in rep.verdicts:
        print(f"  {LEVELS[level]:<4}  {topic}: {text}")
    return 0
