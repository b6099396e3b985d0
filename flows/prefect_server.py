"""Prefect's embedded API server for a flow run: it ends with the flow's process, however it ends.

A flow run on this machine talks to Prefect's temporary API (SQLite) unless a Prefect server
is configured (``PREFECT_API_URL``). Prefect starts that API as a child process and stops it
at exit, but a SIGKILL of the flow process would leave it running; and the flow run of a
killed process stays RUNNING in Prefect. :func:`embedded_server_dies_with_us` makes the first
impossible, :func:`mark_crashed` repairs the second when the next run takes over the store's
lock.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from spectralize.store import LockHolder

__all__ = ["embedded_server_dies_with_us", "mark_crashed"]

_REAPER = """
import sys, time, psutil
pid, started = int(sys.argv[1]), float(sys.argv[2])
sys.stdin.read()  # returns when the flow process exits, however it exits
try:
    server = psutil.Process(pid)
    if abs(server.create_time() - started) < 1e-3:
        try:
            server.wait(5)  # a normal exit stops it itself
        except psutil.TimeoutExpired:
            server.terminate()
            try:
                server.wait(5)
            except psutil.TimeoutExpired:
                server.kill()
except psutil.Error:
    pass
"""
_REAPERS: dict[int, subprocess.Popen] = {}


def embedded_server_dies_with_us() -> None:
    """Start Prefect's embedded API now and make sure it ends with this process.

    Prefect starts it as a child process and stops it at exit, but a SIGKILL of the flow
    process would leave it running (reparented, listening). A tiny watcher process holds
    the read end of a pipe from this process: when this process is gone, however it died,
    the pipe closes and the watcher stops the server. Nothing happens with a configured
    Prefect server (``PREFECT_API_URL``).
    """
    from prefect.settings import PREFECT_API_URL, PREFECT_SERVER_EPHEMERAL_ENABLED

    if PREFECT_API_URL.value() or not PREFECT_SERVER_EPHEMERAL_ENABLED.value():
        return
    import psutil
    from prefect.server.api.server import SubprocessASGIServer

    server = SubprocessASGIServer()
    server.start()
    process = server.server_process
    if process is None or process.pid in _REAPERS:
        return
    started = psutil.Process(process.pid).create_time()
    _REAPERS[process.pid] = subprocess.Popen(
        [sys.executable, "-c", _REAPER, str(process.pid), repr(started)],
        stdin=subprocess.PIPE,
        start_new_session=True,  # not stopped by a Ctrl-C meant for the flow
    )


def mark_crashed(previous: LockHolder, path: Path) -> None:
    """Mark the flow run of a killed writer crashed (it would stay RUNNING in Prefect)."""
    if not previous.flow_run_id:
        return
    try:
        from prefect import get_client
        from prefect.states import Crashed

        embedded_server_dies_with_us()
        with get_client(sync_client=True) as client:
            flow_run = client.read_flow_run(previous.flow_run_id)
            if flow_run.state is not None and flow_run.state.is_final():
                return
            client.set_flow_run_state(
                flow_run.id,
                Crashed(
                    message=f"its process ({previous.describe()}) died without finishing; "
                    f"found when the next run took over {path.name}"
                ),
                force=True,
            )
    except Exception as error:  # a different Prefect API, or the run was deleted
        print(
            f"spectralize: could not mark flow run {previous.flow_run_id} of {previous.describe()} "
            f"as crashed: {type(error).__name__}: {error}",
            file=sys.stderr,
        )
        return
    print(
        f"spectralize: flow run {previous.flow_run_id} of {previous.describe()} was left "
        "RUNNING by a process that is gone; marked it crashed",
        file=sys.stderr,
    )
