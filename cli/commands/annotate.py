"""``zcut annotate LOG.mcap``: the labelling page on 127.0.0.1, with a token in its URL."""

from __future__ import annotations

import argparse
import getpass
import sys
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", type=Path, metavar="LOG.mcap", help="the log to label")
    p.add_argument("--db", type=Path, default=None, metavar="LABELS.sqlite",
                   help="label store (default: LOG.labels.sqlite next to the log)")
    p.add_argument("--port", type=int, default=0, help="port on 127.0.0.1 (default: a free one)")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser")
    who = p.add_mutually_exclusive_group()
    who.add_argument("--annotator", default=None,
                     help="the name every page labels as (default: the login name)")
    who.add_argument("--ask-annotator", action="store_true",
                     help="each page session chooses its annotator name once (several people, one server)")
    p.add_argument("--disagreement", type=Path, default=None, metavar="DIR",
                   help="list only the pixels where the two filters of a comparison disagree (DIR: the -o folder of "
                        "zcut compare on this log): only they can change its verdict")
    add_gate_option(p)
    from cli.commands.common import add_pipeline_options

    add_pipeline_options(p)


#: :data:`annotate.assistant.GATE`, for the help text: that module loads numba and the labelling features
#: (0.5 CPU-s), which ``--help`` does not need; ``tests/cli/test_startup.py`` checks that the two agree
GATE_HELP = 0.9


def add_gate_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--assistant-gate", type=float, default=None, metavar="A",
                   help="the assistant pre-fills its proposals (Y takes them) only when it agrees with your labels "
                        f"on at least this share of the held-out groups (default {GATE_HELP})")


def check_gate(args: argparse.Namespace) -> float:
    """``--assistant-gate``, checked; :data:`annotate.assistant.GATE` when it was not given."""
    from zcut.errors import ParameterError

    g = args.assistant_gate
    if g is None:
        from annotate.assistant import GATE

        g = GATE
    if not (0.0 <= g <= 1.0):
        raise ParameterError(f"--assistant-gate must be in 0..1, got {g}")
    return float(g)


def _default_annotator() -> str:
    try:
        return getpass.getuser()
    except (OSError, KeyError):  # no login name (e.g. a container without a passwd entry)
        return "annotator"


def run(args: argparse.Namespace) -> int:
    import socket
    import webbrowser

    from annotate.server import make_server, open_page
    from cli.commands.common import model_chooser, overrides_of
    from replay.options import warn_bin_model
    from zcut.errors import ParameterError

    if not (0 <= args.port <= 65535):
        raise ParameterError(f"--port must be in 0..65535, got {args.port}")
    gate = check_gate(args)
    if not args.log.is_file():
        raise FileNotFoundError(2, "no such file", str(args.log))
    db = args.db or args.log.with_suffix(".labels.sqlite")
    annotator = None if args.ask_annotator else _default_annotator() if args.annotator is None else args.annotator
    overrides = overrides_of(args)  # bad values fail before the log is read
    if args.config is not None and not Path(args.config).is_file():
        raise FileNotFoundError(2, "no such file", str(args.config))
    choose = model_chooser(args)  # --bin-model, else the log's own (checked before the log is read)
    focus = None
    if getattr(args, "disagreement", None) is not None:
        from annotate.disagreement import load

        focus = load(args.disagreement, args.log)
        a, b = focus.primaries
        print(f"zcut: the page lists only the {focus.n_pixels} pixel(s) where A ({a}) and B ({b}) disagree, "
              f"on {sum(p.size > 0 for _, p, _ in focus.frames.values())} of the {len(focus.frames)} compared "
              f"frame(s) ({args.disagreement})", file=sys.stderr, flush=True)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # restart at once on the same port
    # small responses (a label, the session) otherwise wait ~40 ms for the client's delayed ACK
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    page = None
    try:
        try:
            sock.bind(("127.0.0.1", args.port))
        except OSError as e:
            raise ParameterError(f"--port {args.port}: cannot listen on 127.0.0.1: {e.strerror}") from None
        port = sock.getsockname()[1]
        page = open_page(args.log, db, annotator=annotator, config_path=args.config, choose_bin_model=choose,
                         overrides=overrides, topic=args.topic, assistant_gate=gate,
                         focus=None if focus is None else focus.focus,
                         focus_summary=None if focus is None else focus.summary())
        if page.replay is not None:  # always (open_page opens the log for replay)
            warn_bin_model(page.replay)
            # what the config resolution decided, as every pipeline command says it
            for note in page.replay.notes:
                print(f"zcut: {note}", file=sys.stderr, flush=True)
        fitter = page.catalogue.fitter
        print(f"zcut: {page.fits_note}" if fitter is None else
              f"zcut: fitting {fitter.model_name} to every frame in the background (k = {fitter.k:g}; "
              "docs/labelling.md, \"Judging fits\")", file=sys.stderr, flush=True)
        for other in page.announce(port):
            print(f"warning: {other} serves the same label store {db}: edits from both are kept, "
                  "but the same annotator on both will meet conflicts", file=sys.stderr, flush=True)
        print(f"labels: {db}", flush=True)
        print(f"annotator: {page.annotator or '(each page chooses its own)'}", flush=True)
        url = f"http://127.0.0.1:{port}/?token={page.token}"
        sock.listen(128)  # the URL is printed once connections are accepted (uvicorn serves the backlog)
        print(url, flush=True)
        if not args.no_browser:
            webbrowser.open(url)
        make_server(page).run(sockets=[sock])
    finally:
        if page is not None:
            page.close()
        sock.close()
    return 0
