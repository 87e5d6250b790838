"""Serve a long-running command (the MLflow UI) so that nothing it starts outlives it.

``mlflow server`` is a tree of processes: the CLI, uvicorn (or gunicorn) workers, a job runner
and its huey workers. Stopping only the process we started leaves the rest serving, so the
command runs in its own session (one process group, ``start_new_session``) and, whatever ends
it — SIGTERM, SIGINT, SIGHUP, its own exit, an error — the whole group and every descendant
found by psutil gets SIGTERM, then SIGKILL after a grace period. See the Python docs of
``subprocess.Popen(start_new_session=...)``, ``os.killpg`` and ``signal.signal``, and
``psutil.wait_procs``.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess

import psutil

from orchestration.errors import UserError

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
GRACE_S = 5.0


def check_port_free(host: str, port: int) -> None:
    """A one-line error when nothing could listen on ``host:port`` (taken, or an unknown host),
    before a server starts and fails with tracebacks of its own. SO_REUSEADDR, as servers set it:
    on Linux the probe then fails only for a listening socket, not for a closing connection."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except socket.gaierror as error:
        raise UserError(f"--host {host}: not an address of this machine ({error.strerror})") from error
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as error:
            raise UserError(
                f"cannot listen on {host}:{port} ({error.strerror}); choose another port with --port"
            ) from error


class _Stopped(Exception):
    """Raised in the main thread by a stop signal, to leave the wait and stop the process tree."""


def _raise_stopped(signum: int, _frame: object) -> None:
    raise _Stopped(signum)


def _stop_tree(process: subprocess.Popen, grace_s: float = GRACE_S) -> None:
    """SIGTERM to the process's group and to each of its descendants (one may have left the
    group), SIGKILL to whatever is left after ``grace_s`` seconds; then reap the process."""
    try:
        members = [psutil.Process(process.pid)]
        members += members[0].children(recursive=True)
    except psutil.NoSuchProcess:
        members = []
    for send in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(process.pid, send)
        except (ProcessLookupError, PermissionError):  # the group is gone already
            pass
        for member in members:
            try:
                member.send_signal(send)
            except psutil.NoSuchProcess:
                pass
        _, members = psutil.wait_procs(members, timeout=grace_s)
        if not members:
            break
    process.wait()


def serve(command: list[str]) -> int | None:
    """Run ``command`` in its own session until it exits (its status) or a stop signal arrives
    (None); either way nothing it started is left running. Call from the main thread."""
    previous = {sig: signal.signal(sig, _raise_stopped) for sig in STOP_SIGNALS}
    process = None
    try:
        process = subprocess.Popen(command, start_new_session=True)
        return process.wait()
    except _Stopped:
        return None
    finally:
        for sig in STOP_SIGNALS:  # a second Ctrl-C must not cut the clean-up short
            signal.signal(sig, signal.SIG_IGN)
        if process is not None:
            _stop_tree(process)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
