"""The argument parser of kexp's commands (kexp-diff, kexp-render, kexp-report, kexp-results, kexp-figures, the
golden recorder): a bad command line is one line on stderr, ``<prog>: error: <what> (see <prog> --help)``, and exit
code 2, like every other refusal of theirs (argparse itself prints its usage line first: two lines); ``<prog>
--version`` prints ``<prog> <kexp version>`` and exits 0, whatever else the command requires."""
from __future__ import annotations

import argparse
import os
import sys


class Parser(argparse.ArgumentParser):
    """argparse.ArgumentParser whose errors are one line (subcommands' parsers are of the same class), with a
    ``--version`` option (not on subcommands: ``kexp-results --version``, not ``kexp-results table --version``)."""

    def __init__(self, *args, version: bool = True, **kwargs):
        super().__init__(*args, **kwargs)
        if version:
            from . import __version__
            self.add_argument("--version", action="version", version=f"{self.prog} {__version__}",
                              help="print the tool's name and kexp's version, and exit")

    def add_subparsers(self, **kwargs):
        kwargs.setdefault("parser_class", _SubParser)
        return super().add_subparsers(**kwargs)

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class _SubParser(Parser):
    """A subcommand's parser: one-line errors, no ``--version`` of its own."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, version=False, **kwargs)


def emit(text: str) -> None:
    """Print ``text`` to stdout; a reader that leaves early (``kexp-results table … | head -1``) ends the output
    quietly, not with 'error: Broken pipe' or a traceback, and the command's exit code stays its verdict."""
    try:
        print(text, flush=True)
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # Python's documented recipe
