"""The command line run in-process, for the command tests (tests/ is on sys.path)."""

from __future__ import annotations

from cli.main import main


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """``zcut ARGV`` in this process: (exit status, stdout, stderr)."""
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as e:  # a usage error: argparse exits with the user-error status
        rc = e.code
    cap = capsys.readouterr()
    return rc, cap.out, cap.err
