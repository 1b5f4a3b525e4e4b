"""Experiment scripts as a user runs them: ``run`` starts ``python experiments/SCRIPT ARGS`` in a fresh
interpreter; ``run_in_process`` runs the same ``__main__`` in this process, for the tables of bad inputs.

Each interpreter costs ~1 CPU-second of imports (jax, mujoco) before its flag check, which is what the tables
test: the script's own ``main`` run here goes through the same absl parsing, validation and ``sys.exit(2)``;
what it prints is captured and the exit status read from ``SystemExit``. An uncaught exception (the traceback a
user would see) propagates into the test and fails it. Each table keeps a case or two through ``run``, so the
exit status of a real process is still checked for every entry point.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import runpy
import signal
import subprocess
import sys
from unittest import mock

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(script: str, *args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    """``python experiments/SCRIPT ARGS`` in a subprocess (from the repository root)."""
    return subprocess.run([sys.executable, os.path.join(ROOT, "experiments", script), *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def run_in_process(script: str, *args: str) -> subprocess.CompletedProcess:
    """``experiments/SCRIPT`` run as ``__main__`` here with ``sys.argv = [SCRIPT, *ARGS]``: its exit status
    (``SystemExit``'s code; 0 if it returns) and what it printed. Flags, signal handlers, logging handlers and
    absl's and this package's log levels are restored afterwards, so runs do not see each other's flags."""
    from absl import flags
    from absl import logging as absl_logging
    from absl.testing import flagsaver

    # Every module that defines flags, imported before the flags are saved: a flag first defined inside the
    # saved block is deleted when it ends, and its module (imported once) would not define it again.
    from unilab_jax.apps import cli, hora_cli, mjx_cli, robot_cli  # noqa: F401

    path = os.path.join(ROOT, "experiments", script)
    out, err = io.StringIO(), io.StringIO()
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    root_handlers, verbosity = list(logging.getLogger().handlers), absl_logging.get_verbosity()
    package_level = logging.getLogger("unilab_jax").level
    code = 0
    try:
        with flagsaver.flagsaver(), mock.patch.object(sys, "argv", [path, *args]), \
                contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            flags.FLAGS.unparse_flags()
            try:
                runpy.run_path(path, run_name="__main__")
            except SystemExit as e:  # as the interpreter exits: None is 0, a message is printed and 1
                code = e.code if isinstance(e.code, int) else 0 if e.code is None else 1
                if not isinstance(e.code, (int, type(None))):
                    print(e.code, file=sys.stderr)
    finally:
        for s, h in handlers.items():
            signal.signal(s, h)
        logging.getLogger().handlers[:] = root_handlers
        absl_logging.set_verbosity(verbosity)
        logging.getLogger("unilab_jax").setLevel(package_level)
    return subprocess.CompletedProcess([path, *args], code, out.getvalue(), err.getvalue())
