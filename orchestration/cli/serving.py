"""The verbs that show a project: `m2d2m models` (what each trained model knows), `ui` (the MLflow
UI on its runs) and `serve` (the web page and HTTP API, orchestration/web/).
"""

from __future__ import annotations

import argparse

from orchestration.cli.arguments import add_max_seconds, port_number, positive_int
from orchestration.errors import UserError
from orchestration.project import require_project


def _models(args: argparse.Namespace) -> None:
    from orchestration.model_summary import summary_lines

    print("\n".join(summary_lines(args.dataset)))


def _ui(args: argparse.Namespace) -> None:
    import os

    from orchestration.serving import check_port_free, serve
    from orchestration.tracking import tracking_uri, ui_command, ui_runs_page

    if os.environ.get("MLFLOW_TRACKING_URI", "").startswith("http"):
        print(f"the runs are on the tracking server: open {ui_runs_page(os.environ['MLFLOW_TRACKING_URI'])}")
        return
    require_project()  # elsewhere it would open, and so create, an empty store
    check_port_free(args.host, args.port)
    page = ui_runs_page(f"http://{args.host}:{args.port}")
    print(f"MLflow UI on {tracking_uri()}: {page}  (Ctrl-C stops it)", flush=True)
    status = serve(ui_command(args.host, args.port))
    if status:
        raise UserError(f"the MLflow UI stopped with status {status}; its messages are above")
    print("stopped the MLflow UI and everything it started")


def _serve(args: argparse.Namespace) -> None:
    from orchestration.generate.prompts import length_cap
    from orchestration.model_summary import also_trained
    from orchestration.serving import check_port_free
    from orchestration.web.app import ServeSettings
    from orchestration.web.server import serve, server_token

    require_project()  # elsewhere it would serve no model
    token = server_token(args.host, args.token)
    check_port_free(args.host, args.port)
    settings = ServeSettings(
        dataset=args.dataset,
        token=token,
        max_seconds=length_cap(args.max_seconds),
        queue=args.queue,
        max_batch=args.max_batch,
        device=args.device,
        track=not args.no_track,
        mlflow_ui=args.mlflow_ui,
        max_rig_bytes=args.max_rig_mb << 20,
    )
    host = f"[{args.host}]" if ":" in args.host else args.host
    print(
        f"m2d2m on http://{host}:{args.port}/ (the API's documentation: /docs); Ctrl-C or SIGTERM stops it",
        flush=True,
    )
    others = also_trained(args.dataset)
    if others:
        print(others, flush=True)
    serve(settings, args.host, args.port)
    print("stopped: the requests in flight were answered")


def add_models(verbs) -> None:
    listing = verbs.add_parser(
        "models", help="what each trained model knows: its actions, lengths, words, methods and defaults"
    )
    listing.add_argument("--dataset", help="whose runs to describe (default: every dataset with a trained model)")
    listing.set_defaults(run=_models)


def add_ui(verbs) -> None:
    ui = verbs.add_parser("ui", help="the MLflow UI on the project's tracking store")
    ui.add_argument("--port", type=port_number, default=5000)
    ui.add_argument("--host", default="127.0.0.1", help="127.0.0.1 (default) keeps it on this machine")
    ui.set_defaults(run=_ui)


def add_serve(verbs) -> None:
    from orchestration.web.server import TOKEN_VARIABLE

    serve = verbs.add_parser("serve", help="a web page and an HTTP API for generating and comparing motions")
    serve.add_argument("--port", type=port_number, default=8000)
    serve.add_argument(
        "--host", default="127.0.0.1", help="127.0.0.1 (default) keeps it on this machine; another needs a token"
    )
    serve.add_argument("--token", help=f"what every API call must carry (default: ${TOKEN_VARIABLE})")
    serve.add_argument("--dataset", default="synthetic", help="whose runs to serve (default synthetic)")
    add_max_seconds(serve, "a request for more seconds of motion than this")
    serve.add_argument("--queue", type=positive_int, default=64, help="requests that may wait (default 64)")
    serve.add_argument(
        "--max-batch", type=positive_int, default=16, help="sequences sampled in one call at most (default 16)"
    )
    serve.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    serve.add_argument(
        "--max-rig-mb", type=positive_int, default=64, help="the largest character's file one may upload (default 64)"
    )
    serve.add_argument("--mlflow-ui", help="the MLflow UI's address for links to runs (default: make ui's)")
    serve.add_argument("--no-track", action="store_true", help="do not log the generations to MLflow")
    serve.set_defaults(run=_serve)
