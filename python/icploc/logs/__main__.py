"""``python -m icploc.logs LOG [LOG ...]``: print what each log holds (scans, beams, stamps)."""

from __future__ import annotations

import argparse
import sys

from icploc.logs import LogFormatError, load_log


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m icploc.logs", description=__doc__)
    ap.add_argument("logs", nargs="+", help="CARMEN log (.log/.gz), ROS 1/2 bag, or recording")
    ap.add_argument("--format", default=None, help="force a format (carmen, rosbag, recorded)")
    ap.add_argument(
        "--strict", action="store_true", help="refuse a malformed line or impossible reading"
    )
    args = ap.parse_args(argv)
    status = 0
    for path in args.logs:
        try:
            opts = {"strict": True} if args.strict else {}
            print(load_log(path, format=args.format, **opts).info.summary())
        except (LogFormatError, OSError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            status = 1
    return status


if __name__ == "__main__":
    raise SystemExit(main())
