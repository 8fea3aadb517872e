"""The argument parser of kexp's commands (kexp-diff, kexp-render, kexp-report, kexp-results, kexp-figures, the
golden recorder): a bad command line is one line on stderr, ``<prog>: error: <what> (see <prog> --help)``, and exit
code 2, like every other refusal of theirs (argparse itself prints its usage line first: two lines)."""
from __future__ import annotations

import argparse
import os
import sys


class Parser(argparse.ArgumentParser):
    """argparse.ArgumentParser whose errors are one line (subcommands' parsers are of the same class)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def emit(text: str) -> None:
    """Print ``text`` to stdout; a reader that leaves early (``kexp-results table … | head -1``) ends the output
    quietly, not with 'error: Broken pipe' or a traceback, and the command's exit code stays its verdict."""
    try:
        print(text, flush=True)
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # Python's documented recipe
