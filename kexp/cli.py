"""The argument parser of kexp's commands (kexp-diff, kexp-render, kexp-report, kexp-results, kexp-figures, the
golden recorder): a bad command line is one line on stderr, ``<prog>: error: <what> (see <prog> --help)``, and exit
code 2, like every other refusal of theirs (argparse itself prints its usage line first: two lines)."""
from __future__ import annotations

import argparse


class Parser(argparse.ArgumentParser):
    """argparse.ArgumentParser whose errors are one line (subcommands' parsers are of the same class)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")
