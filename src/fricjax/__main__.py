"""The `fricjax` program (its console script calls `main`) and `python -m fricjax`.

Its first statement makes SIGINT and SIGTERM set a flag (`_estimation.loop._interrupts`), before the command line is
imported: a signal at any moment after Python's start-up and these first imports (~60 ms) ends the run with exit
status 130 and nothing written, without a traceback. Importing `fricjax` as a library changes no signal handler.
"""

from ._estimation.loop._interrupts import catch_signals

catch_signals()

import sys  # noqa: E402

from ._cli import main as _main  # noqa: E402


def main() -> int:
    """The program: `fricjax ARGS` (`fricjax._cli.main` on `sys.argv`)."""
    return _main()


if __name__ == "__main__":
    sys.exit(main())
