"""``python -m bentray.service serve|worker``: the same as ``bentray serve`` plus a standalone worker."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from bentray.service.settings import SettingsError


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bentray.service")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("serve", help="run the HTTP API and its job processes")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--workers", type=int, default=None, help="job processes (default BENTRAY_WORKERS or 1)")
    p.add_argument("--data-dir", default=None, help="default BENTRAY_DATA_DIR or ./bentray-data")
    p.add_argument("--log-level", default="info")
    w = sub.add_parser("worker", help="run job processes only (the API runs elsewhere with --workers 0)")
    w.add_argument("--workers", type=int, default=None)
    w.add_argument("--data-dir", default=None)
    w.add_argument("--log-level", default="info")
    args = parser.parse_args(argv)
    from bentray.service.server import run_worker, serve

    try:
        if args.command == "serve":
            serve(args.host, args.port, args.workers, args.data_dir, args.log_level)
        else:
            run_worker(args.workers, args.data_dir, args.log_level)
    except SettingsError as exc:
        print(f"bentray {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
