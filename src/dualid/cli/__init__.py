"""The ``dualid`` command line. It only parses arguments, calls the library and prints.

Each command group lives in its own module and registers itself on ``app``.
"""

from dualid.cli.app import app

__all__ = ["app"]
