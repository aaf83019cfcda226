"""The ``gonio`` command line's parsers: every subcommand's arguments, help and choices.

Nothing here imports what a command does: each subcommand's function is named by its ``"module:attr"``
(:func:`~gonio.cli.common.command`) and imported when the command runs, and the choices and reference
lists in the help come from :mod:`gonio.registries`. So ``gonio --version`` and ``gonio <command>
--help`` import neither pydantic, numpy, scipy nor Dr.Jit (tests/test_cli_startup.py).
"""

from __future__ import annotations

from gonio.cli.common import ReferenceFormatter, add_force, command, seed_type
from gonio.jit import BACKENDS
from gonio.registries import EXPORT_FORMATS, PLOT_KINDS, SIM_DETECTORS

__all__ = ["add_campaign_parsers", "add_batch_parsers", "add_result_parsers", "add_hardware_parsers",
           "add_cluster_arguments", "grid_help"]


def add_campaign_parsers(sub, fmt) -> None:
    """``plan``, ``simulate``, ``status``, ``materials``, ``config`` and ``run``."""
    sp = sub.add_parser("plan", formatter_class=ReferenceFormatter, epilog=grid_help(),
                        help="count and time a plan without moving anything")
    sp.add_argument("--grid", required=True, help="GRID, e.g. iso:step=5, full:step=15, merl:stride=4 "
                    "(every kind and option below)")
    sp.add_argument("--config", default=None,
                    help="gantry config: a TOML file or a shipped config's name (default: sim)")
    sp.add_argument("--json", action="store_true", help="one JSON object instead of the report")
    sp.set_defaults(func=command("gonio.cli.campaigns:cmd_plan"))
    ss = sub.add_parser("simulate", formatter_class=fmt, help="run a whole campaign on the simulated gantry")
    ss.add_argument("material",
                    help="MATERIAL, e.g. lambert:albedo=0.8 or cook-torrance:d=beckmann,m=0.2,metal=gold "
                         "(every model, key and range: gonio materials)")
    ss.add_argument("--grid", required=True, help="GRID, e.g. iso:step=10 (every kind and option: gonio "
                    "plan --help)")
    ss.add_argument("--out", required=True, help="campaign folder (an unfinished campaign there is resumed)")
    ss.add_argument("--config", default=None,
                    help="gantry config: a TOML file or a shipped config's name (default: sim)")
    ss.add_argument("--seed", type=seed_type, default=0,
                    help="seed of the simulated detector's random numbers")
    ss.add_argument("--detector", choices=SIM_DETECTORS.names(), default=None,
                    help="the simulated detector (default: the config's [detector.sim] kind): "
                         + "; ".join(f"{e.name}: {e.summary}" for e in SIM_DETECTORS.entries()))
    ss.add_argument("--backend", choices=BACKENDS, default=None,
                    help="Dr.Jit backend of the simulation (default: $GONIO_BACKEND, else cuda when a CUDA "
                         "device is present, else llvm; the config's [detector.sim] backend, where set, "
                         "wins for the detector)")
    ss.add_argument("--clear-fault", action="store_true",
                    help="clear the campaign's latched fault (after fixing its cause) and resume")
    ss.add_argument("--quiet", action="store_true", help="no progress output")
    ss.add_argument("--export", default=None, metavar="FORMATS",
                    help="exports written into the campaign folder once it is finished, comma-separated: "
                         + ", ".join(EXPORT_FORMATS.names()) + " (gonio export --help says what each is)")
    ss.set_defaults(func=command("gonio.cli.campaigns:cmd_simulate"))
    st = sub.add_parser("status", formatter_class=fmt,
                        help="a campaign's state, progress, ETA and last fault, from its folder (read-only, "
                             "safe while it runs) or from the daemon")
    st.add_argument("dir", metavar="DIR|ID", help="campaign folder, or the id of a campaign of the daemon "
                    "(e.g. c00001)")
    st.add_argument("--url", default=None, help="ask this daemon about campaign ID (default for an ID: "
                    "GONIO_URL, else http://127.0.0.1:8765)")
    st.add_argument("--json", action="store_true", help="one JSON object")
    st.set_defaults(func=command("gonio.cli.campaigns:cmd_status"))
    sm = sub.add_parser("materials", formatter_class=fmt,
                        help="the material models of MATERIAL strings: keys, ranges, defaults and rules")
    sm.add_argument("name", nargs="?", default=None, help="one model (default: every model)")
    sm.set_defaults(func=command("gonio.cli.campaigns:cmd_materials"))
    sc = sub.add_parser("config", formatter_class=fmt, help="list or print the shipped gantry configs")
    sc.add_argument("action", choices=["list", "show"])
    sc.add_argument("name", nargs="?", help="config name (for show) or a path")
    sc.set_defaults(func=command("gonio.cli.campaigns:cmd_config"))
    sr = sub.add_parser("run", formatter_class=fmt,
                        help="run a whole campaign on the configured (real, emulated or mixed) gantry")
    sr.add_argument("--config", required=True, help="gantry config: a TOML file or a shipped config's name")
    sr.add_argument("--grid", required=True, help="GRID, e.g. iso:step=10 (every kind and option: "
                    "gonio plan --help)")
    sr.add_argument("--out", required=True, help="campaign folder (an unfinished campaign there is resumed)")
    sr.add_argument("--sample", required=True, help="name of the sample measured")
    sr.add_argument("--material", default=None,
                    help="MATERIAL a simulated detector renders (dry runs: config detector driver 'sim')")
    sr.add_argument("--seed", type=seed_type, default=0, help="seed of simulated devices' random numbers")
    sr.add_argument("--clear-fault", action="store_true",
                    help="clear the campaign's latched fault (after fixing its cause) and resume")
    sr.add_argument("--quiet", action="store_true", help="no progress output")
    sr.set_defaults(func=command("gonio.cli.campaigns:cmd_run"))


def add_batch_parsers(sub, fmt) -> None:
    """``batch``."""
    sb = sub.add_parser("batch", formatter_class=fmt,
                        help="simulate many materials on Dask into one xarray/Zarr store")
    sb.add_argument("materials", metavar="MATERIALS",
                    help="a file of MATERIAL lines, or one MATERIAL whose options may span values: "
                         "key=A..BxN (N values from A to B) or key=a|b (each), e.g. "
                         "'ggx:alpha=0.02..0.5x20,metal=gold|copper' (40 materials)")
    sb.add_argument("--grid", required=True,
                    help="GRID of every campaign, e.g. iso:step=15 (gonio plan --help)")
    sb.add_argument("--out", required=True, help="the store, a folder, e.g. batch.zarr (a store of the same "
                    "batch is continued: only the missing materials run)")
    sb.add_argument("--seed", type=seed_type, default=0, help="seed of every campaign's simulated detector")
    sb.add_argument("--config", default=None,
                    help="gantry config with a simulated detector (default: sim)")
    add_cluster_arguments(sb)
    sb.add_argument("--quiet", action="store_true", help="no progress output")
    sb.set_defaults(func=command("gonio.cli.batch:cmd_batch"))


#: The most local workers of ``--workers`` (a local cluster runs one process each).
MAX_WORKERS = 256


def workers_type(text: str) -> int:
    """``--workers``: an integer from 1 to :data:`MAX_WORKERS`."""
    import argparse

    try:
        n = int(text)
    except ValueError:
        n = None
    if n is None or not 1 <= n <= MAX_WORKERS:
        raise argparse.ArgumentTypeError(f"must be an integer from 1 to {MAX_WORKERS}, got {text!r}")
    return n


def add_cluster_arguments(parser) -> None:
    """``--workers N | --scheduler ADDRESS``: where a batch's tasks run."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=workers_type, default=None,
                       help="local worker processes (default: the CPU count)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="an existing Dask scheduler, e.g. tcp://10.0.0.5:8786 (its workers need this "
                            "gonio version)")


def add_result_parsers(sub, fmt) -> None:
    """``fit``, ``export``, ``plot`` and ``report`` (a finished campaign)."""
    sf = sub.add_parser("fit", formatter_class=fmt,
                        help="fit a reflectance model to a finished campaign's measured samples")
    sf.add_argument("dir", metavar="SOURCE", help="finished campaign folder (or its brdf.h5); or a batch "
                    "store (gonio batch) or a folder of finished campaigns: each fitted, one CSV table")
    sf.add_argument("--model", required=True,
                    help="a material model, fitted with every key the material has, rho_d included: "
                         "lambert, phong, modified-phong, blinn-phong, normalized-blinn-phong, ward, "
                         "cook-torrance, ggx; NAME-lobe: the lobe alone (rho_d held at 0); ':key=value,...' "
                         "holds keys fixed or picks the form (d=blinn, fresnel=dielectric, metal=gold), "
                         "':anisotropic' for ward/ggx")
    sf.add_argument("--channels", default=None, help="channels to fit, e.g. R,G,B or G (default: all)")
    sf.add_argument("--loss", default="auto", choices=["auto", "chi2", "cos"],
                    help="chi2: weighted by the measured stddev; cos: cos θi cos θo (f_model − f); auto: "
                         "chi2 when the data have stddevs")
    sf.add_argument("--starts", type=int, default=4, help="number of starts; the best fit wins")
    sf.add_argument("--backend", choices=BACKENDS, default=None,
                    help="Dr.Jit backend of the model evaluations (default: $GONIO_BACKEND, else cuda when a "
                         "CUDA device is present, else llvm)")
    sf.add_argument("--out", metavar="FIT.json", default=None,
                    help="write parameters, uncertainties, loss and residual statistics as JSON (many "
                         "sources: the CSV table; default: stdout)")
    add_cluster_arguments(sf)
    sf.add_argument("--quiet", action="store_true", help="only the MATERIAL string")
    add_force(sf)
    sf.set_defaults(func=command("gonio.cli.results:cmd_fit"))
    folders = [e.name for e in EXPORT_FORMATS.entries() if e.extra.get("folder")]
    se = sub.add_parser("export", formatter_class=ReferenceFormatter,
                        epilog="FORMAT is one of:\n" + EXPORT_FORMATS.help(),
                        help="export a finished campaign's BRDF to a renderer's or a tool's file format")
    se.add_argument("dir", metavar="CAMPAIGN_DIR", help="finished campaign folder")
    se.add_argument("--format", required=True, metavar="FORMAT", help="the format (below)")
    se.add_argument("--out", required=True, metavar="FILE",
                    help="output file (a folder for " + (", ".join(folders) or "none") + ")")
    add_force(se)
    se.set_defaults(func=command("gonio.cli.results:cmd_export"))
    sg = sub.add_parser("plot", formatter_class=ReferenceFormatter,
                        epilog="KIND is one of:\n" + PLOT_KINDS.help(),
                        help="draw a finished campaign's BRDF (a PNG/PDF figure, or the slice's float "
                             "values as EXR)")
    sg.add_argument("dir", metavar="CAMPAIGN_DIR", help="finished campaign folder")
    sg.add_argument("--kind", required=True, metavar="KIND", help="the kind of plot (below)")
    sg.add_argument("--out", required=True, metavar="FILE", help="FILE.png, FILE.pdf or FILE.exr")
    sg.add_argument("--theta-i", type=float, default=30.0, help="θi of the hemisphere plot, degrees")
    sg.add_argument("--phi-i", type=float, default=0.0, help="φi (plane of incidence), degrees")
    add_force(sg)
    sg.set_defaults(func=command("gonio.cli.results:cmd_plot"))
    sq = sub.add_parser("report", formatter_class=fmt,
                        help="a finished campaign's report as one self-contained HTML page: the campaign, "
                             "its calibration, data checks, and several models fitted side by side")
    sq.add_argument("dir", metavar="CAMPAIGN_DIR", help="finished campaign folder")
    sq.add_argument("--out", required=True, metavar="REPORT.html", help="the page to write")
    sq.add_argument("--models", default=None, metavar="MODELS",
                    help="comma-separated fit MODELs as for gonio fit (default: lambert, ward, "
                         "cook-torrance, ggx: gonio.report.DEFAULT_MODELS)")
    add_force(sq)
    sq.set_defaults(func=command("gonio.cli.results:cmd_report"))


def add_hardware_parsers(sub, fmt) -> None:
    """``emulate`` and ``gantry``."""
    se = sub.add_parser("emulate", formatter_class=fmt,
                        help="run the emulated devices of a config until SIGINT/SIGTERM (they power up as "
                             "hardware does: `gonio gantry reference` first)")
    se.add_argument("--config", required=True, help="gantry config: a TOML file or a shipped config's name")
    se.add_argument("--material", default="lambert:albedo=0.5", help="MATERIAL the emulated detector sees")
    se.add_argument("--seed", type=seed_type, default=0, help="seed of the emulated detector's readings")
    se.add_argument("--write-config", default=None, metavar="PATH",
                    help="write the config with the emulators' ptys and urls to PATH (removed at exit)")
    se.add_argument("--any-port", action="store_true",
                    help="serve Modbus TCP on free loopback ports, not the ports the config names")
    se.set_defaults(func=command("gonio.cli.hardware:cmd_emulate"))
    sg = sub.add_parser("gantry", formatter_class=fmt, help="manual control of the configured gantry")
    sg.add_argument("action", choices=["status", "home", "move", "jog", "stop", "reboot", "reference"],
                    help="status: read only, writes nothing; reference: find where the axes are after "
                         "power-up (each axis's configured method); home/move/jog are refused until then")
    sg.add_argument("--config", required=True, help="gantry config: a TOML file or a shipped config's name")
    sg.add_argument("--theta-i", type=float, default=None, help="move: θi (°)")
    sg.add_argument("--phi-i", type=float, default=None, help="move: φi (°)")
    sg.add_argument("--theta-o", type=float, default=None, help="move: θo (°)")
    sg.add_argument("--phi-o", type=float, default=None, help="move: φo (°)")
    sg.add_argument("--axes", default=None, help="move: axis positions a,b,c,d (°) in the design's order")
    sg.add_argument("--axis", default=None, help="jog: the axis; reboot, reference: only this axis")
    sg.add_argument("--by", type=float, default=None, help="jog: degrees to move by (signed)")
    sg.add_argument("--json", action="store_true", help="status: one JSON object")
    sg.set_defaults(func=command("gonio.cli.hardware:cmd_gantry"))


def grid_help(width: int = 100) -> str:
    """Every grid kind, option and order of the registries, as text (``gonio plan --help``).

    >>> text = grid_help()
    >>> "isotropy" in text and "merl:stride=K" in text and "serpentine" in text
    True
    """
    import textwrap

    from gonio.registries import GRID_KINDS, GRID_OPTIONS, ORDERS

    #: How each kind's size is spelled (``"budget"``: poses or budget_s, as its options say).
    sizes = {"step": "step=S", "stride": "stride=K", "budget": "poses=N (or budget_s=T)"}
    lines = ["GRID is KIND:OPTION=VALUE,... with KIND one of:"]
    for kind in GRID_KINDS.entries():
        lines += textwrap.wrap(f"{kind.name}:{sizes[kind.extra['size']]}  {kind.summary}; "
                               f"options: {', '.join(kind.extra['options'])}", width,
                               initial_indent="  ", subsequent_indent="      ")
    lines.append("options:")
    for option in GRID_OPTIONS.entries():
        lines += textwrap.wrap(f"{option.name}: {option.summary}", width, initial_indent="  ",
                               subsequent_indent="      ")
    lines.append("orders (option order):")
    lines.append(ORDERS.help(width, indent="  "))
    return "\n".join(lines)
