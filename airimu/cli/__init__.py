"""The ``airimu`` command line (entry point ``airimu.cli:main``; ``python -m airimu.cli`` as torchrun launches it).
The commands register on ``airimu.cli.app.app`` from ``airimu.cli.fuse`` and ``airimu.cli.train``."""

from __future__ import annotations

import typer

from airimu.cli import fuse, train  # noqa: F401 (each registers its commands on the app)
from airimu.cli.app import app

__all__ = ["app", "main"]


def main() -> None:
    """Console entry point: the toolkit's own errors (bad files, configs, checkpoints, exports, graphs) print as
    one line (``AIRIMU_DEBUG=1``: the traceback)."""
    import os
    import sys

    try:
        code = app(standalone_mode=False)  # typer's own usage errors come back here, to print as one line too
    except typer.TyperException as error:  # a bad flag or value: typer itself would draw a multi-line box
        context = getattr(error, "ctx", None)
        command = context.command_path if context is not None and context.command_path else "airimu"
        print(f"airimu: error: {' '.join(error.format_message().split())} (see {command} --help)", file=sys.stderr)
        sys.exit(2)
    except typer.Abort:
        print("airimu: aborted", file=sys.stderr)
        sys.exit(1)
    except Exception as error:
        from airimu_core.errors import AirImuError

        if os.environ.get("AIRIMU_DEBUG") or not isinstance(error, AirImuError):
            raise
        print(f"airimu: error: {error}", file=sys.stderr)
        sys.exit(2)
    sys.exit(code if isinstance(code, int) else 0)
