"""CLI verbs for the service (registered in :data:`bentray.clients.cli.COMMANDS`).

    bentray serve [--host 127.0.0.1] [--port 8000] [--workers N] [--data-dir DIR]
    bentray submit JOB.json [--file F ...] [--wait] [--out DIR] [--quiet]
    bentray status [ID]
    bentray fetch ID --out DIR [--name FILE ...]
    bentray cancel ID

The client verbs talk to ``--url`` (default ``$BENTRAY_URL`` or http://127.0.0.1:8000) with the key
``--key`` (default ``$BENTRAY_API_KEY``). ``submit --wait --out DIR`` writes the same files as
``bentray run JOB.json --out DIR``. Exit status: 0 success; 1 a failed or cancelled job or a service
error; 2 a rejected job (HTTP 422, the ``field.path: reason`` lines on stderr) or bad arguments.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

if TYPE_CHECKING:
    from bentray.clients.client import BentrayClient
    from bentray.service.models import JobInfo

__all__ = ["SERVICE_COMMANDS"]


def _error(exc: Exception, code: int | None = None) -> Exception:
    from bentray.clients.cli import CommandError
    from bentray.clients.client import ServiceError

    if isinstance(exc, ServiceError):
        return CommandError(
            f"{exc.detail} (HTTP {exc.status})"
            if exc.status != 422
            else f"the service rejected the job:\n{exc.detail}",
            code=2 if exc.status == 422 else 1,
        )
    return CommandError(f"cannot reach the service: {exc}", code=code or 1)


def _client(args: argparse.Namespace) -> BentrayClient:
    from bentray.clients.client import BentrayClient

    return BentrayClient(args.url, api_key=args.key)


def _call(args: argparse.Namespace, fn: Callable[[BentrayClient], int]) -> int:
    import httpx

    from bentray.clients.client import ServiceError

    try:
        with _client(args) as client:
            return fn(client)
    except (ServiceError, httpx.HTTPError) as exc:
        raise _error(exc) from None


# ---------------------------------------------------------------------------------------------
def cmd_serve(args: argparse.Namespace) -> int:
    from bentray.clients.cli import CommandError
    from bentray.service.settings import SettingsError

    try:
        from bentray.service.server import serve
    except ImportError as exc:
        raise CommandError(f"the service needs its extras: pip install 'bentray[service]' ({exc})", code=2) from None
    try:
        serve(args.host, args.port, args.workers, args.data_dir, args.log_level)
    except SettingsError as exc:
        raise CommandError(str(exc), code=2) from None
    return 0


def _print_info(info: JobInfo, out: TextIO | None = None) -> None:
    out = out or sys.stdout
    line = f"{info.id}  {info.name:<24} {info.status:<10} {info.stage:<12} {100 * info.progress:5.1f}%"
    if info.error:
        line += f"  {info.error}"
    print(line, file=out)


def cmd_submit(args: argparse.Namespace) -> int:
    from bentray.clients.cli import CommandError

    job_path = Path(args.job)
    if not job_path.is_file():
        raise CommandError(f"{job_path}: no such job file", code=2)
    if args.out and not args.wait:
        raise CommandError("--out needs --wait (or use 'bentray fetch ID --out DIR' later)", code=2)

    def run(client: BentrayClient) -> int:
        info = client.submit(job_path, files=args.file)
        print(f"submitted {info.id} ({info.name})", file=sys.stderr)
        if not args.wait:
            print(info.id)
            return 0
        final = client.wait(info.id, progress=not args.quiet)
        _print_info(final)
        if final.status != "succeeded":
            raise CommandError(f"job {final.id} {final.status}" + (f": {final.error}" if final.error else ""))
        if args.out:
            written = client.download(final.id, args.out)
            print("wrote: " + ", ".join(str(p) for p in written))
        return 0

    return _call(args, run)


def cmd_status(args: argparse.Namespace) -> int:
    def run(client: BentrayClient) -> int:
        infos = [client.get(args.id)] if args.id else client.list()
        for info in infos:
            _print_info(info)
        if args.id and infos[0].results:
            print("results: " + ", ".join(infos[0].results))
        return 0

    return _call(args, run)


def cmd_fetch(args: argparse.Namespace) -> int:
    def run(client: BentrayClient) -> int:
        written = client.download(args.id, args.out, names=args.name)
        print("wrote: " + ", ".join(str(p) for p in written))
        return 0

    return _call(args, run)


def cmd_cancel(args: argparse.Namespace) -> int:
    def run(client: BentrayClient) -> int:
        info = client.cancel(args.id)
        print(
            f"{args.id} deleted"
            if info is None
            else f"{args.id} {info.status}"
            + (" (cancelling)" if info is not None and info.cancel_requested and not info.finished else "")
        )
        return 0

    return _call(args, run)


# ---------------------------------------------------------------------------------------------
def _client_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--url",
        default=os.environ.get("BENTRAY_URL", "http://127.0.0.1:8000"),
        help="service address (default $BENTRAY_URL or http://127.0.0.1:8000)",
    )
    p.add_argument(
        "--key", default=os.environ.get("BENTRAY_API_KEY") or None, help="API key (default $BENTRAY_API_KEY)"
    )


def _add_serve(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "serve",
        help="run the HTTP service (API and job processes)",
        description="Run the HTTP service; settings from BENTRAY_* variables (see service/settings.py).",
    )
    p.add_argument("--host", default="127.0.0.1", help="bind address (non-loopback needs API keys)")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--workers", type=int, default=None, help="concurrent job processes (0: API only)")
    p.add_argument("--data-dir", default=None, help="job store and files (default $BENTRAY_DATA_DIR)")
    p.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    p.set_defaults(func=cmd_serve)


def _add_submit(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "submit",
        help="submit a job file to the service",
        description="Submit a job; files it names beside it are uploaded with it.",
    )
    p.add_argument("job", help="job file (JSON)")
    p.add_argument("--file", action="append", default=[], help="extra input file to upload (repeatable)")
    p.add_argument("--wait", action="store_true", help="wait for the job, showing progress")
    p.add_argument("--out", default=None, help="with --wait: download the results into this folder")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _client_options(p)
    p.set_defaults(func=cmd_submit)


def _add_status(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("status", help="show one job or list your jobs")
    p.add_argument("id", nargs="?", default=None)
    _client_options(p)
    p.set_defaults(func=cmd_status)


def _add_fetch(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("fetch", help="download a finished job's results")
    p.add_argument("id")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--name", nargs="+", default=None, help="only these result files")
    _client_options(p)
    p.set_defaults(func=cmd_fetch)


def _add_cancel(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("cancel", help="cancel a queued or running job, or delete a finished one")
    p.add_argument("id")
    _client_options(p)
    p.set_defaults(func=cmd_cancel)


SERVICE_COMMANDS = [_add_serve, _add_submit, _add_status, _add_fetch, _add_cancel]
