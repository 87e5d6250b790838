"""`m2d2m serve` under load: latency (p50, p95) and throughput at 1, 4 and 16 concurrent clients
on loopback, each client asking for the same four actions with its own seed, against the demo
models (after `make demo`). Every level runs ``--rounds`` rounds in which all its clients send at
once; the goal is that a round of 16 finishes within 3× a round of one, because the server samples
requests that arrive together in one batch. Bounded: ``--budget-s`` ends a level early.

    python bench/serve.py [--dataset synthetic] [--model m2d2m] [--clients 1 4 16] [--rounds 3]

Prints Markdown for BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
ACTIONS = [
    {"text": "a person walks forward", "seconds": 3.0},
    {"text": "a person jumps", "seconds": 2.0},
    {"text": "a person waves their right hand", "seconds": 3.0},
    {"text": "a person sits down", "seconds": 3.0},
]


def start_server(dataset: str, port: int, track: bool, max_batch: int) -> subprocess.Popen:
    command = [sys.executable, "-m", "orchestration.cli", "serve", "--dataset", dataset, "--port", str(port)]
    command += ["--max-batch", str(max_batch)]
    server = subprocess.Popen(command + ([] if track else ["--no-track"]), cwd=ROOT, env={**os.environ})
    deadline = time.monotonic() + 120
    while True:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=5).status_code == 200:
                return server
        except httpx.TransportError:
            if server.poll() is not None or time.monotonic() > deadline:
                raise SystemExit("the server did not start; its messages are above") from None
            time.sleep(0.5)


async def one_request(client: httpx.AsyncClient, model: str, seed: int) -> float:
    started = time.perf_counter()
    answer = await client.post("/api/generate", json={"model": model, "actions": ACTIONS, "seed": seed})
    if answer.status_code != 200:
        raise SystemExit(f"the server answered {answer.status_code}: {answer.text}")
    return time.perf_counter() - started


async def level(base: str, model: str, clients: int, rounds: int, budget_s: float) -> dict[str, float]:
    """``rounds`` rounds of ``clients`` simultaneous requests: every latency and each round's time."""
    latencies: list[float] = []
    round_times: list[float] = []
    async with httpx.AsyncClient(base_url=base, timeout=600, limits=httpx.Limits(max_connections=64)) as client:
        began = time.perf_counter()
        for index in range(rounds):
            started = time.perf_counter()
            seeds = range(index * clients, (index + 1) * clients)
            latencies += await asyncio.gather(*(one_request(client, model, seed) for seed in seeds))
            round_times.append(time.perf_counter() - started)
            if time.perf_counter() - began > budget_s:
                break
    ordered = sorted(latencies)
    return {
        "clients": clients,
        "requests": len(latencies),
        "p50": statistics.median(ordered),
        "p95": ordered[min(len(ordered) - 1, round(0.95 * (len(ordered) - 1)))],
        "round": statistics.median(round_times),
        "throughput": len(latencies) / sum(round_times),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="synthetic")
    parser.add_argument("--model", default="m2d2m")
    parser.add_argument("--clients", type=int, nargs="+", default=[1, 4, 16])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--budget-s", type=float, default=300.0, help="seconds after which a level stops")
    parser.add_argument("--port", type=int, default=8765)
    parser.add_argument("--no-track", action="store_true", help="serve without logging to MLflow")
    parser.add_argument("--max-batch", type=int, default=16, help="the server's --max-batch (1: no batching)")
    args = parser.parse_args()

    server = start_server(args.dataset, args.port, not args.no_track, args.max_batch)
    base = f"http://127.0.0.1:{args.port}"
    try:
        asyncio.run(level(base, args.model, 1, 1, args.budget_s))  # loads the model
        results = [asyncio.run(level(base, args.model, c, args.rounds, args.budget_s)) for c in args.clients]
        health = httpx.get(f"{base}/api/health").json()
    finally:
        server.terminate()
        server.wait(timeout=120)
    one = next((r["round"] for r in results if r["clients"] == 1), None)
    print(
        f"\n`m2d2m serve`, {args.model}, four actions (11 s of motion) a request, MLflow "
        f"{'off' if args.no_track else 'on'}; {os.cpu_count()} CPU cores\n"
    )
    print("| clients | requests | p50 latency (s) | p95 latency (s) | round (s) | × one | requests/s |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for r in results:
        ratio = f"{r['round'] / one:.2f}" if one else "–"
        print(
            f"| {r['clients']} | {r['requests']} | {r['p50']:.2f} | {r['p95']:.2f} | {r['round']:.2f} | {ratio} "
            f"| {r['throughput']:.2f} |"
        )
    print(f"\nlargest batch {health['largest_batch']}, {health['batches']} batches for {health['served']} requests")


if __name__ == "__main__":
    main()
