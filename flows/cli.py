"""The ``spectralize`` command line.

spectralize nodes                       registered nodes, their groups and parameters
spectralize flows                       named flows
spectralize validate STORE [--deep]     check a run store: files, checksums, contract, values
spectralize clean STORE                 remove unfinished writes a killed run left behind
spectralize run FLOW STORE [--set k=v]  run a flow (resumes: finished nodes are skipped)
spectralize serve ROOT [--cron ...]     nightly processing of new runs (needs a Prefect server)
spectralize demo [--capture DIR]        make the sample run (or capture folder) and process it
spectralize ingest CAPTURE_DIR STORE    a gantry's capture folder into a run store (incremental)
spectralize report STORE [--out DIR]    the HTML report of a run (with or without ground truth)
spectralize export STORE OUT --format envi|netcdf [--image LABEL ...]   cubes for other software

Options anywhere on the line: --debug (full tracebacks), -v/--verbose (Prefect's log lines).
Run `spectralize COMMAND --help` for a command's options, their defaults and allowed values.
"""

# Answering --help, nodes, flows, validate or export imports neither Prefect (imported by
# flows/runtime.py when a flow runs) nor matplotlib (reports): every import of ours (but the
# light `--set` text of flows/assignments.py) and of heavy libraries happens inside the command
# that needs it.

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

from .assignments import UsageError, parse_assignments
from .command_checks import check_run, check_store

__all__ = ["main", "build_parser"]


def _cmd_nodes(args: argparse.Namespace) -> int:
    from spectralize.flows.node_listing import node_listing

    text = node_listing(use_cache=not args.refresh)
    if not text:
        print("no nodes are installed (is spectralize installed with pip?)")
        return 1
    print(text, end="")
    return 0


def _cmd_flows(args: argparse.Namespace) -> int:
    from spectralize.flows.pipelines import FLOWS

    for name, definition in sorted(FLOWS.items()):
        print(f"{name}: {definition.description}")
        print(f"    nodes: {' -> '.join(step.node for step in definition.steps)}")
    return 0


def _cmd_validate(args: argparse.Namespace) -> int:
    check_store(args.store)
    from spectralize.store import RunStore

    store = RunStore.open(args.store)
    groups = store.groups()
    required: list[str] = []
    if args.flow:
        from spectralize.flows.pipelines import flow_inputs

        required = flow_inputs(args.flow)
    problems = store.validate(deep=args.deep, required=required)
    if args.flow and not problems:  # the value checks the flow's nodes make before computing
        from spectralize.flows.preflight import flow_value_problems

        problems = flow_value_problems(store, args.flow)
    leftovers = store.staging_leftovers()
    print(f"{store.path}: {len(groups)} group(s): {', '.join(groups) or 'none'}")
    for warning in leftovers:
        print(f"warning: {warning}", file=sys.stderr)
    if problems:
        print(f"{len(problems)} problem(s):", file=sys.stderr)
        for problem in problems:
            print(f"  - {problem}", file=sys.stderr)
        return 1
    checked = "files, checksums" if args.deep else "files"
    print(f"valid: every group follows the run-store contract ({checked}, values checked)")
    return 0


def _cmd_clean(args: argparse.Namespace) -> int:
    check_store(args.store)
    from spectralize.store import RunStore

    store = RunStore.open(args.store)
    removed = store.clean()
    for name in removed:
        print(f"removed unfinished write .staging/{name}")
    print(f"{store.path}: {len(removed)} unfinished write(s) removed")
    return 0


def _print_report(report) -> None:
    print(f"flow {report.flow!r} on {report.store}")
    for step in report.steps:
        timing = f"{step.seconds:.1f} s" if step.status == "ran" else "up to date"
        peak = getattr(step, "peak_rss_gb", None)  # the node's peak resident set (this process)
        memory = f"{peak:.2f} GB" if peak is not None else ""
        print(
            f"  {step.node:<24} {step.status:<8} {timing:<12} {memory:<9} -> {', '.join(step.outputs)}"
        )
        if getattr(step, "reason", ""):
            print(f"      ran again: {step.reason}")
    if getattr(report, "peak_rss_gb", None) is not None:
        print(f"peak resident memory of this process: {report.peak_rss_gb:.2f} GB")
    if report.report:
        print(f"report: {report.report}")


def _cmd_run(args: argparse.Namespace) -> int:
    parameters = parse_assignments(args.set)
    check_run(args.flow, args.store, parameters, dask_address=args.dask_address)
    from spectralize.flows import run_flow
    from spectralize.flows.progress import console_progress

    with console_progress(verbose=args.verbose):
        report = run_flow(
            args.flow,
            args.store,
            parameters=parameters,
            retries=args.retries,
            dask_address=args.dask_address,
            verify=args.verify,
            strict=args.strict,
        )
    _print_report(report)
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    parameters = parse_assignments(args.set)
    check_run("btf" if args.capture else "demo", None, parameters)
    from spectralize.flows.demo import DEMO_STORE, run_capture_demo, run_demo
    from spectralize.flows.progress import console_progress

    with console_progress(verbose=args.verbose):
        if args.capture:
            store, report, _ = run_capture_demo(
                args.capture, args.store or DEMO_STORE, recipe=args.recipe, parameters=parameters
            )
        else:
            store, report = run_demo(args.store or DEMO_STORE, parameters=parameters)
    _print_report(report)
    print(f"results: {store.path}")
    print(f"  groups: {', '.join(store.groups())}")
    print(f"  in Python: spectralize.store.open_run({str(store.path)!r}).read('spectra')")
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    import os

    from spectralize.flows.schedule import serve_nightly
    from spectralize.schemas import SpectralizeError

    if not os.environ.get("PREFECT_API_URL"):
        from prefect.settings import PREFECT_API_URL

        if not PREFECT_API_URL.value():
            raise SpectralizeError(
                "schedules need a Prefect server: start one with `prefect server start "
                "--background` and `prefect config set PREFECT_API_URL="
                "http://127.0.0.1:4200/api`, then run `spectralize serve` again"
            )
    print(
        f"serving nightly processing of {args.root} ({args.flow!r} flow, cron {args.cron!r});"
        " Ctrl-C stops it"
    )
    serve_nightly(
        args.root,
        flow_name=args.flow,
        cron=args.cron,
        pattern=args.pattern,
        dask_address=args.dask_address,
        output_root=args.output_root,
        settle_seconds=60.0 * args.settle_minutes,
    )
    return 0


def _cmd_ingest(args: argparse.Namespace) -> int:
    from spectralize.flows.ingest import ingest

    report = ingest(args.capture_dir, args.store, progress=print)
    read, kept = report.frames_read, report.frames_copied
    print(f"ingested {report.capture} into {report.store} in {report.seconds:.1f} s")
    for group, status in report.groups.items():
        print(f"  {group:<22} {status}")
    print(f"  {read} frame(s) read from files, {kept} kept from the store")
    print(f"next: spectralize run btf {report.store}")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    check_store(args.store)
    from spectralize.flows.pipelines import report_directory
    from spectralize.flows.report import write_run_report

    pixels = [tuple(int(v) for v in p.split(",")) for p in args.pixel] or None
    path = write_run_report(
        args.store,
        directory=args.out or report_directory(args.store),
        max_images=args.max_images,
        pixels=pixels,
    )
    print(f"report: {path}")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    check_store(args.store)
    from spectralize.flows.export import export

    files = export(
        args.store,
        args.out,
        format=args.format,
        group=args.group,
        images=args.image or None,
        per_image=args.per_image,
        progress=print,
    )
    if len(files) <= 4:
        for path in files:
            print(f"wrote {path}")
    else:
        print(f"wrote {len(files)} files to {files[0].parent}")
    return 0


class _HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the layout of descriptions and epilogs; adds ``(default: X)`` to an option's
    help when it has a default worth saying (not ``None``, ``False`` or empty) and its help
    does not already name one."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (
            default is None
            or default is False
            or default is argparse.SUPPRESS
            or default == []
            or "default" in text
            or not action.option_strings
        ):
            return text
        return f"{text} (default: %(default)s)"


class _Parser(argparse.ArgumentParser):
    """An argument parser whose epilog may be computed only when its help is shown (the
    flow names need the node engine, which ``spectralize --help`` does not import)."""

    def __init__(self, *args: Any, lazy_epilog: Callable[[], str] | None = None, **kwargs: Any):
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)
        self.lazy_epilog = lazy_epilog

    def format_help(self) -> str:
        if self.lazy_epilog is not None:
            self.epilog = self.lazy_epilog()
        return super().format_help()


def _flows_epilog() -> str:
    from spectralize.flows.pipelines import FLOW_DESCRIPTIONS

    lines = ["flows (FLOW):"]
    lines += [f"  {name:<10} {text}" for name, text in sorted(FLOW_DESCRIPTIONS.items())]
    lines.append("  or the name of one node (see 'spectralize nodes'), run on its own")
    lines.append("")
    lines.append("parameters: 'spectralize nodes' prints each as --set NODE.PARAM=DEFAULT")
    return "\n".join(lines)


_SET_HELP = (
    "node parameter NODE.PARAM=VALUE or PARAM=VALUE (repeatable); VALUE is JSON (null, true, "
    '[0.5,0.0], "text"), a Python literal (None, (0.5, 0.0)) or bare text (block-jacobi-pcg); '
    "'spectralize nodes' lists every parameter with its default in this syntax"
)


def build_parser() -> argparse.ArgumentParser:
    """The ``spectralize`` parser: the options read anywhere, then one sub-parser per command."""
    parser = _Parser(
        prog="spectralize",
        description="Turns the measurement runs of a spectral BTF gantry into calibrated "
        "spectral image cubes (Fast Capture of Spectral Image Series).",
        epilog="Options anywhere on the line: --debug (full tracebacks), -v/--verbose "
        "(Prefect's log lines).\nRun 'spectralize COMMAND --help' for a command's options, "
        "their defaults and allowed values.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an error")
    parser.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="show Prefect's log lines (INFO) instead of the progress display",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_command in _COMMANDS:  # in the order --help lists them
        add_command(commands)
    return parser


_Commands = Any  # argparse's sub-parsers action (its class is private)


def _add_nodes(commands: _Commands) -> None:
    nodes = commands.add_parser(
        "nodes", help="list registered nodes, their parameters, defaults and allowed values"
    )
    nodes.add_argument(
        "--refresh",
        action="store_true",
        help="load every node instead of reading the cached listing (which is renewed "
        "whenever a node's source, a plugin or a version changes)",
    )
    nodes.set_defaults(handler=_cmd_nodes)


def _add_flows(commands: _Commands) -> None:
    commands.add_parser("flows", help="list named flows").set_defaults(handler=_cmd_flows)


def _add_validate(commands: _Commands) -> None:
    validate = commands.add_parser("validate", help="check a run store against the contract")
    validate.add_argument("store")
    validate.add_argument(
        "--deep", action="store_true", help="recompute every chunk's checksum (reads all data)"
    )
    validate.add_argument(
        "--flow",
        default=None,
        help="also require the groups this flow reads (a flow of 'spectralize flows', e.g. btf)",
    )
    validate.set_defaults(handler=_cmd_validate)


def _add_clean(commands: _Commands) -> None:
    clean = commands.add_parser("clean", help="remove unfinished writes of killed runs")
    clean.add_argument("store")
    clean.set_defaults(handler=_cmd_clean)


def _add_run(commands: _Commands) -> None:
    run = commands.add_parser(
        "run",
        help="run a flow against a store (finished nodes are skipped)",
        description="Run a flow against a run store. Nodes whose results are up to date are "
        "skipped; an interrupted write resumes where it stopped. Progress: a bar of the image "
        "sets' work done and one per running solver, each with the time left measured from the "
        "solver's convergence rate and time per iteration, on a terminal; the same numbers as "
        "plain lines otherwise; -v shows Prefect's log lines instead. The flow name, the store "
        "path, every --set and --dask-address are checked first, in well under a second.",
        lazy_epilog=_flows_epilog,
    )
    run.add_argument("flow", help="a flow (listed below) or a node name")
    run.add_argument("store", help="the run store (a zarr directory)")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help=_SET_HELP)
    run.add_argument("--retries", type=int, default=0, help="Prefect task retries per node")
    run.add_argument(
        "--dask-address",
        default=os.environ.get("DASK_SCHEDULER_ADDRESS") or None,
        help="address of an existing dask.distributed scheduler (default: $DASK_SCHEDULER_ADDRESS, "
        "else local threads)",
    )
    run.add_argument(
        "--verify",
        action="store_true",
        help="recompute every checksum of the groups the flow reads or writes before trusting "
        "them (one read of those groups); by default every chunk is checked as it is read",
    )
    run.add_argument(
        "--strict",
        action="store_true",
        help="stop (exit 2) before the reconstruction when a calibration node's check of its "
        "result warns (a chart cross-check far above a sane gantry's, a response that does not "
        "rise, C not of RGB shape, Q rippling, a registration a period of the target away or "
        "pairs that disagree); by default the warnings are printed",
    )
    run.set_defaults(handler=_cmd_run)


def _add_serve(commands: _Commands) -> None:
    serve = commands.add_parser("serve", help="serve scheduled processing of a folder of runs")
    serve.add_argument("root", help="folder whose run stores (*.zarr) are processed")
    serve.add_argument("--flow", default="btf", help="flow to run on each store")
    serve.add_argument("--cron", default="0 2 * * *", help="schedule (cron syntax)")
    serve.add_argument("--pattern", default="*.zarr", help="which entries of ROOT are runs")
    serve.add_argument("--dask-address", default=None, help="existing dask scheduler")
    serve.add_argument(
        "--output-root",
        default=None,
        help="ROOT holds capture folders: ingest each complete one into OUTPUT_ROOT/<name>.zarr",
    )
    serve.add_argument(
        "--settle-minutes",
        type=float,
        default=5.0,
        help="a capture folder changed more recently than this is left for the next run",
    )
    serve.set_defaults(handler=_cmd_serve)


def _add_ingest(commands: _Commands) -> None:
    ingest = commands.add_parser("ingest", help="ingest a capture folder into a run store")
    ingest.add_argument("capture_dir", help="folder with manifest.csv, capture.toml, calibration/")
    ingest.add_argument("store", help="run store to create or extend")
    ingest.set_defaults(handler=_cmd_ingest)


def _add_report(commands: _Commands) -> None:
    report = commands.add_parser("report", help="write the HTML report of a run store")
    report.add_argument("store")
    report.add_argument("--out", default=None, help="folder of index.html (default: STORE-report)")
    report.add_argument("--max-images", type=int, default=24, help="images with figures")
    report.add_argument(
        "--pixel",
        action="append",
        default=[],
        metavar="Y,X",
        help="a pixel whose spectrum is drawn on the first image (besides those chosen per camera)",
    )
    report.set_defaults(handler=_cmd_report)


def _add_export(commands: _Commands) -> None:
    export = commands.add_parser("export", help="export spectral cubes as ENVI or netCDF")
    export.add_argument("store")
    export.add_argument("out", help="ENVI: a folder; netCDF: a .nc file (or a folder)")
    export.add_argument(
        "--format", choices=("envi", "netcdf"), required=True, help="one of: %(choices)s"
    )
    export.add_argument("--group", default="spectra", help="cube group")
    export.add_argument(
        "--image",
        type=int,
        action="append",
        default=[],
        metavar="LABEL",
        help="image label (repeatable; default: every image)",
    )
    export.add_argument("--per-image", action="store_true", help="netCDF: one file per image")
    export.set_defaults(handler=_cmd_export)


def _add_demo(commands: _Commands) -> None:
    demo = commands.add_parser("demo", help="make the sample run and process it")
    demo.add_argument(
        "--store", default=None, help="where to put the demo run store (default: demo/run.zarr)"
    )
    demo.add_argument(
        "--capture",
        default=None,
        metavar="DIR",
        help="the real path: write a sample capture folder here, ingest it, run btf",
    )
    demo.add_argument("--recipe", default="demo", help="recipe of the sample capture folder")
    demo.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="node parameter, e.g. simulate.recipe=tiny (repeatable; syntax: see run --help)",
    )
    demo.set_defaults(handler=_cmd_demo)


_COMMANDS: tuple[Callable[[_Commands], None], ...] = (
    _add_nodes,
    _add_flows,
    _add_validate,
    _add_clean,
    _add_run,
    _add_serve,
    _add_ingest,
    _add_report,
    _add_export,
    _add_demo,
)
"""Each command's sub-parser, in the order ``spectralize --help`` lists them."""


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("spectralize")
    except PackageNotFoundError:
        return "unknown (not installed)"


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"spectralize: warning: {message}", file=file or sys.stderr)


_ANYWHERE = {"--debug": "debug", "-v": "verbose", "--verbose": "verbose"}


def _is_ours(error: BaseException) -> bool:
    """Whether ``error`` is a :class:`UsageError` or a :class:`SpectralizeError` (not imported
    for it: if the errors module was never imported, none of its errors can have been raised)."""
    if isinstance(error, UsageError):
        return True
    errors = sys.modules.get("spectralize.schemas.errors")
    return errors is not None and isinstance(error, errors.SpectralizeError)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; errors exit 2 with a message (``--debug``: with the traceback).

    ``--debug`` and ``-v``/``--verbose`` are accepted anywhere on the line
    (``spectralize run btf run.zarr --debug -v``).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    flags = {
        name: any(a in argv for a, n in _ANYWHERE.items() if n == name) for name in ("debug", "verbose")
    }
    args = build_parser().parse_args([a for a in argv if a not in _ANYWHERE])
    args.debug, args.verbose = flags["debug"], flags["verbose"]
    if not args.debug:
        import warnings

        warnings.showwarning = _show_warning
    try:
        return args.handler(args)
    except KeyboardInterrupt:
        import logging

        from .signals import quiet_cut_off_io

        # zarr's I/O tasks cut off by the interrupt would each log "Task was destroyed" at exit
        logging.getLogger("asyncio").setLevel(logging.CRITICAL)
        quiet_cut_off_io()  # and their coroutines closed after the loop: "Event loop is closed"
        print(f"spectralize {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as error:
        if args.debug:
            import traceback

            traceback.print_exc()
        ours = _is_ours(error)
        kind = "" if ours else f"{type(error).__name__}: "
        print(f"spectralize {args.command}: error: {kind}{error}", file=sys.stderr)
        for note in getattr(error, "__notes__", ()):
            print(f"  ({note})", file=sys.stderr)
        if not args.debug and not ours:
            print("  (run again with --debug for the traceback)", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
