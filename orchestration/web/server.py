"""Run the application under uvicorn: on loopback by default, elsewhere only with a token.

uvicorn's own signal handling gives the shutdown asked of a service: on SIGTERM or Ctrl-C it stops
accepting connections, lets the requests in flight finish, then runs the application's shutdown,
which lets the sampling thread finish its queue (see uvicorn's docs, "Server behavior").
"""

from __future__ import annotations

import os
import signal
from typing import TYPE_CHECKING

from orchestration.errors import UserError

if TYPE_CHECKING:  # the application loads torch; the command line reads this module without it
    from orchestration.web.service import ServeSettings

TOKEN_VARIABLE = "M2D2M_SERVE_TOKEN"
LOOPBACK = ("127.0.0.1", "localhost", "::1")


def server_token(host: str, given: str | None) -> str | None:
    """The token API calls must carry: ``--token``, else :data:`TOKEN_VARIABLE`; required when
    ``host`` is not loopback, since anyone who can reach the port could then use the machine."""
    token = given if given is not None else os.environ.get(TOKEN_VARIABLE) or None
    if token is not None and len(token) < 8:
        raise UserError(
            "a token of at least 8 characters, please (e.g. python -c 'import secrets; print(secrets.token_urlsafe())')"
        )
    if token is None and host not in LOOPBACK:
        raise UserError(
            f"--host {host} opens the API beyond this machine: give --token or set {TOKEN_VARIABLE}, "
            "which every API call must then carry"
        )
    return token


def serve(settings: ServeSettings, host: str, port: int) -> None:
    """Serve until SIGTERM or Ctrl-C; the requests in flight finish first."""
    import uvicorn

    from orchestration.web.app import create_app

    config = uvicorn.Config(create_app(settings), host=host, port=port, log_level="warning", lifespan="on")
    # uvicorn raises the stopping signal again once it has shut down, for the handler it found:
    # with Python's defaults that is a death by SIGTERM or a KeyboardInterrupt after a clean stop
    previous = {number: signal.signal(number, lambda *_: None) for number in (signal.SIGTERM, signal.SIGINT)}
    try:
        uvicorn.Server(config).run()
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
