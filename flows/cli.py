"""The ``spectralize`` command line.

spectralize nodes                       registered nodes, their groups and parameters
spectralize flows                       named flows
spectralize validate STORE              check a run store against the contract
spectralize run FLOW STORE [--set k=v]  run a flow (resumes: finished nodes are skipped)
spectralize serve ROOT [--cron ...]     nightly processing of new runs (needs a Prefect server)
spectralize demo                        make the sample run and process it
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

from spectralize.schemas import SpectralizeError

__all__ = ["main"]


def _parse_value(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _parse_assignments(items: Sequence[str]) -> dict[str, Any]:
    values = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise SpectralizeError(
                f"--set expects KEY=VALUE (e.g. dark_average.frames_per_chunk=8), got {item!r}"
            )
        values[key.strip()] = _parse_value(value.strip())
    return values


def _cmd_nodes(args: argparse.Namespace) -> int:
    from spectralize.engine import registry

    nodes = registry()
    if not nodes:
        print("no nodes are installed (is spectralize installed with pip?)")
        return 1
    for name, entry in sorted(nodes.items()):
        node = entry.node
        print(f"{name}  (version {node.version})")
        if node.description:
            print(f"    {node.description}")
        print(f"    from:    {entry.source}")
        inputs = ", ".join(f"{arg} <- {group}" for arg, group in node.inputs.items()) or "none"
        print(f"    inputs:  {inputs}")
        print(f"    outputs: {', '.join(node.outputs)}")
        choices = node.parameter_choices()
        for pname, ptype, default, description in node.describe_parameters():
            print(f"    --set {name}.{pname}={default!r}  ({ptype}) {description}".rstrip())
            if pname in choices:
                print(f"        one of: {', '.join(choices[pname]) or 'none'}")
    return 0


def _cmd_flows(args: argparse.Namespace) -> int:
    from spectralize.flows import FLOWS

    for name, definition in sorted(FLOWS.items()):
        print(f"{name}: {definition.description}")
        print(f"    nodes: {' -> '.join(step.node for step in definition.steps)}")
    return 0


def _cmd_validate(args: argparse.Namespace) -> int:
    from spectralize.schemas import RunStore

    store = RunStore.open(args.store)
    groups = store.groups()
    problems = store.validate()
    print(f"{store.path}: {len(groups)} group(s): {', '.join(groups) or 'none'}")
    if problems:
        print(f"{len(problems)} problem(s):", file=sys.stderr)
        for problem in problems:
            print(f"  - {problem}", file=sys.stderr)
        return 1
    print("valid: every group follows the run-store contract")
    return 0


def _print_report(report) -> None:
    print(f"flow {report.flow!r} on {report.store}")
    for step in report.steps:
        timing = f"{step.seconds:.1f} s" if step.status == "ran" else "up to date"
        print(f"  {step.node:<24} {step.status:<8} {timing:<12} -> {', '.join(step.outputs)}")
    if report.report:
        print(f"report: {report.report}")


def _cmd_run(args: argparse.Namespace) -> int:
    from spectralize.flows import run_flow

    report = run_flow(
        args.flow,
        args.store,
        parameters=_parse_assignments(args.set),
        retries=args.retries,
        dask_address=args.dask_address,
    )
    _print_report(report)
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from spectralize.flows.demo import DEMO_STORE, run_demo

    store, report = run_demo(args.store or DEMO_STORE, parameters=_parse_assignments(args.set))
    _print_report(report)
    print(f"results: {store.path}")
    print(f"  groups: {', '.join(store.groups())}")
    print(f"  in Python: spectralize.schemas.open_run({str(store.path)!r}).read('spectra')")
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    import os

    from spectralize.flows.schedule import serve_nightly

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
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="spectralize", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser("nodes", help="list registered nodes").set_defaults(handler=_cmd_nodes)
    commands.add_parser("flows", help="list named flows").set_defaults(handler=_cmd_flows)
    validate = commands.add_parser("validate", help="check a run store against the contract")
    validate.add_argument("store")
    validate.set_defaults(handler=_cmd_validate)
    run = commands.add_parser("run", help="run a flow against a store")
    run.add_argument("flow")
    run.add_argument("store")
    run.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="node parameter: NODE.PARAM=VALUE or PARAM=VALUE (repeatable)",
    )
    run.add_argument("--retries", type=int, default=0, help="Prefect task retries per node")
    run.add_argument(
        "--dask-address",
        default=None,
        help="address of an existing dask.distributed scheduler (default: local)",
    )
    run.set_defaults(handler=_cmd_run)
    serve = commands.add_parser("serve", help="serve scheduled processing of a folder of runs")
    serve.add_argument("root", help="folder whose run stores (*.zarr) are processed")
    serve.add_argument("--flow", default="btf", help="flow to run on each store")
    serve.add_argument("--cron", default="0 2 * * *", help="schedule (cron syntax)")
    serve.add_argument("--pattern", default="*.zarr", help="which entries of ROOT are runs")
    serve.add_argument("--dask-address", default=None, help="existing dask scheduler")
    serve.set_defaults(handler=_cmd_serve)
    demo = commands.add_parser("demo", help="make the sample run and process it")
    demo.add_argument("--store", default=None, help="where to put the demo run store")
    demo.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="node parameter, e.g. simulate.recipe=tiny (repeatable)",
    )
    demo.set_defaults(handler=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.handler(args)
    except SpectralizeError as error:
        print(f"spectralize {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
