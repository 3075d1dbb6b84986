"""`ndf-view RUN_DIR [--port 8080]`: look at a run in a web browser (needs the [viewer] extra).

Shows the deformed mesh coloured by displacement, membrane strain, bending strain or energy
density with a colour bar, the reference surface as a ghost, probes on every frame, obstacles
by their scene names, a slider over the trajectory frames, a camera framing the mesh ("fit to
view") and a plot of Π and the Newton decrement per iteration. Serves until interrupted
(Ctrl-C).

While `ndf-sim` is still writing RUN_DIR (its RUN_DIR.incomplete is held by the live run), the
page shows the stage in progress and the convergence plot as the run reports it (from its
progress.jsonl, read every second), and the finished run when it ends (reload the page).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from taichi_ndf.cli.common import description


def _port(text: str) -> int:
    value = int(text)
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be in [0, 65535], got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ndf-view", description=description(__doc__))
    p.add_argument("run", type=Path, help="run directory written by ndf-sim (or being written: "
                   "then followed live)")
    p.add_argument("--port", type=_port, default=8080, help="TCP port (default 8080)")
    p.add_argument("--host", default="127.0.0.1",
                   help="interface to listen on (default 127.0.0.1, this machine only: from "
                   "elsewhere use ssh -L PORT:127.0.0.1:PORT; 0.0.0.0 listens on all)")
    p.add_argument("--frame", type=int, default=None,
                   help="trajectory frame shown first (0 = the first load step, -1 = the "
                   "last; default the last)")
    p.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        import logging

        from taichi_ndf.extras import MissingExtra
        from taichi_ndf.viewer.app import require_viewer
        from taichi_ndf.viewer.live import LiveViewer, live_run

        logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                            format="%(levelname)s %(name)s: %(message)s")
        require_viewer()
        live = live_run(args.run)
        if live is not None:
            viewer = LiveViewer(live, host=args.host, port=args.port)
            name = f"{live.name} (running; the finished run opens when it ends)"
        else:
            if args.run.name.endswith(".incomplete"):
                raise FileNotFoundError(f"{args.run} is the staging folder of a run that is not "
                                        "running (ndf-sim --resume continues it)")
            viewer = finished_viewer(args.run, args, args.port)
            name = viewer.run.name
    except (MissingExtra, ValueError, FileNotFoundError, OSError) as err:
        print(f"ndf-view: error: {err}", file=sys.stderr)
        return 2
    taken = "" if viewer.port == args.port else f"; port {args.port} was taken"
    print(f"ndf-view: {name} at {viewer.url}  (Ctrl-C stops{taken})", flush=True)
    if args.host == "127.0.0.1":
        print(f"  on a remote machine: ssh -L {viewer.port}:127.0.0.1:{viewer.port} HOST, then "
              f"open http://127.0.0.1:{viewer.port}", flush=True)
    try:
        while True:
            time.sleep(1.0)
            if live is not None and viewer.poll():
                port = viewer.port
                viewer.stop()
                try:
                    viewer = finished_viewer(live, args, port)
                except (ValueError, FileNotFoundError, OSError) as err:
                    print(f"ndf-view: error: the run ended but cannot be shown: {err}",
                          file=sys.stderr)
                    return 2
                live = None
                print(f"ndf-view: {viewer.run.name} finished; reload the page at {viewer.url}",
                      flush=True)
    except KeyboardInterrupt:
        viewer.stop()
    return 0


def finished_viewer(path: Path, args: argparse.Namespace, port: int):
    """The `RunViewer` of the finished run in `path`."""
    from taichi_ndf.io.run_files import read_run
    from taichi_ndf.viewer.app import RunViewer

    return RunViewer(read_run(path), host=args.host, port=port, frame=args.frame)


if __name__ == "__main__":
    sys.exit(main())
