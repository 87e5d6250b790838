"""Serve a long-running command (the MLflow UI) so that nothing it starts outlives it.

``mlflow server`` is a tree of processes: the CLI, uvicorn (or gunicorn) workers, a job runner
and its huey workers. Stopping only the process we started leaves the rest serving, so the
command runs in its own session (one process group, ``start_new_session``) and, whatever ends
it — SIGTERM, SIGINT, SIGHUP, its own exit, an error — the whole group and every descendant
found by psutil gets SIGTERM, then SIGKILL after a grace period. A SIGKILL of this process
runs none of that, so on Linux a small watcher process of ours (``python -m
orchestration.serving PARENT ROOT``, in a session of its own) does it instead: the kernel sends it
SIGTERM when its parent dies (``PR_SET_PDEATHSIG``, prctl(2)). See the Python docs of
``subprocess.Popen(start_new_session=...)``, ``os.killpg`` and ``signal.signal``, and
``psutil.wait_procs``.
"""

from __future__ import annotations

import ctypes
import os
import signal
import socket
import subprocess
import sys

import psutil

from orchestration.errors import UserError

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
GRACE_S = 5.0
PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


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


def _stop_tree(root: int, grace_s: float = GRACE_S) -> None:
    """SIGTERM to the group of ``root`` (a session leader) and to each of its descendants (one
    may have left the group), SIGKILL to whatever is left after ``grace_s`` seconds."""
    try:
        members = [psutil.Process(root)]
        members += members[0].children(recursive=True)
    except psutil.NoSuchProcess:
        members = []
    for send in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(root, send)
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


def serve(command: list[str]) -> int | None:
    """Run ``command`` in its own session until it exits (its status) or a stop signal arrives
    (None); either way nothing it started is left running. Call from the main thread."""
    previous = {sig: signal.signal(sig, _raise_stopped) for sig in STOP_SIGNALS}
    process = watcher = None
    try:
        process = subprocess.Popen(command, start_new_session=True)
        watcher = _start_watcher(process.pid)
        return process.wait()
    except _Stopped:
        return None
    finally:
        for sig in STOP_SIGNALS:  # a second Ctrl-C must not cut the clean-up short
            signal.signal(sig, signal.SIG_IGN)
        if process is not None:
            _stop_tree(process.pid)
            process.wait()
        if watcher is not None:  # nothing left to watch over
            watcher.kill()
            watcher.wait()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _start_watcher(root: int) -> subprocess.Popen | None:
    """The process that stops the tree of ``root`` should this one be killed (Linux; None elsewhere)."""
    if not sys.platform.startswith("linux"):
        return None
    command = [sys.executable, "-m", "orchestration.serving", str(os.getpid()), str(root)]
    return subprocess.Popen(command, start_new_session=True, stdin=subprocess.DEVNULL)


def _watch_over(parent: int, root: int) -> None:
    """Wait for SIGTERM, which the kernel sends when ``parent`` dies, then stop the tree of ``root``."""
    signal.signal(signal.SIGTERM, _raise_stopped)
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    try:
        while os.getppid() == parent:  # a parent that died before prctl: stop at once
            signal.pause()
    except _Stopped:
        pass
    _stop_tree(root)


if __name__ == "__main__":
    _watch_over(*(int(argument) for argument in sys.argv[1:3]))
