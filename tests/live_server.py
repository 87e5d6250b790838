"""A real uvicorn server of `m2d2m serve`'s application in a thread of the test process, for tests
that need concurrent clients, disconnects or a browser."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import uvicorn
from fastapi import FastAPI

from orchestration.web.app import ServeSettings, create_app
from tests.helpers import free_port


@contextmanager
def live_server(settings: ServeSettings) -> Iterator[tuple[str, FastAPI]]:
    """The application on a free loopback port: its base URL and the app (its ``state.service``)."""
    app = create_app(settings)
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=free_port(), log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "the server did not start"
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{server.config.port}", app
    finally:
        server.should_exit = True
        thread.join(timeout=60)
