"""Helpers shared by the command modules: printing errors, exit codes and output folders."""

from __future__ import annotations

import os
import sys
import time
import warnings
from contextlib import contextmanager
from pathlib import Path

import typer
from rich.console import Console
from rich.text import Text

console = Console(stderr=True, soft_wrap=True)  # never hard-wrap messages: users grep them

EXIT_OK = 0
EXIT_FAILED = 1  # a requested computation (e.g. one fit method) failed; other outputs were written
EXIT_BAD_INPUT = 2  # usage, files, config, logs, model or output directory (typer's code for usage errors)


def error_exit_code(exc: BaseException) -> int:
    """EXIT_BAD_INPUT for errors in what the user gave (data, config, model, files); EXIT_FAILED for a
    computation that failed on valid input (solver, identifiability, metric, simulation)."""
    from dualid.errors import ConfigError, ConsistencyError, DataError, ModelError

    if isinstance(exc, (DataError, ConfigError, ModelError, ConsistencyError, OSError)):
        return EXIT_BAD_INPUT
    return EXIT_FAILED


def error_message(exc: BaseException) -> str:
    """The user-facing text of an error; a bare OSError as 'FILE: reason'."""
    from dualid.errors import DualidError

    if isinstance(exc, OSError) and not isinstance(exc, DualidError) and exc.strerror:
        where = f"{exc.filename}: " if exc.filename is not None else ""
        return f"{where}{exc.strerror}"
    return str(exc)


def print_error(exc_or_message) -> None:
    """'error: …' on stderr; the message is plain text (no rich markup: '[m/s²]' and 'q1[rad]' survive)."""
    message = exc_or_message if isinstance(exc_or_message, str) else error_message(exc_or_message)
    console.print(Text("error: ", style="bold red") + Text(message), highlight=False)


def print_warning(message: str) -> None:
    console.print(Text("warning: ", style="yellow") + Text(message), highlight=False)


def fail(message: str, code: int = EXIT_BAD_INPUT) -> None:
    """Print an error (plain text) and exit with ``code`` (default: bad input)."""
    print_error(message)
    raise typer.Exit(code)


def show_warnings(caught: list[warnings.WarningMessage]) -> None:
    for message in dict.fromkeys(str(w.message) for w in caught):  # each once, in order
        print_warning(message)


def output_dir(path: Path, force: bool) -> Path:
    """Check --out against the output-directory policy before any work (dualid.report.outdir);
    an OutputError propagates to the app's handler (exit 2)."""
    from dualid.report.outdir import check_output_dir

    return check_output_dir(path, force)


BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> None:
    """Run BLAS on one thread in this process unless the user chose a thread count (any of BLAS_THREADS set).
    A fit's products are small (N·n × p with p a few dozen): a second BLAS thread saves no time there but
    spins, so it costs CPU (AᵀA of 8,000 × 26: 7 ms of CPU with two OpenBLAS threads, 0.4 ms with one; the
    DFKI fit's ``dm`` 14-19 s against 1.5 s on a 2-core machine). Takes effect only before numpy is imported."""
    if "numpy" in sys.modules or any(v in os.environ for v in BLAS_THREADS):
        return
    for v in BLAS_THREADS:
        os.environ[v] = "1"


def no_mujoco_rendering() -> None:
    """MUJOCO_GL=disable unless set: a command that only writes MJCF files does not load MuJoCo's OpenGL backend
    (glfw, about 0.1 s of CPU at import)."""
    if "mujoco" not in sys.modules:
        os.environ.setdefault("MUJOCO_GL", "disable")


def progress_line(message: str, start: float | None = None) -> None:
    """One plain progress line on stderr ('[  12.3 s] message'), flushed: what a redirected log keeps."""
    elapsed = "" if start is None else f"[{time.perf_counter() - start:7.1f} s] "
    print(f"{elapsed}{message}", file=sys.stderr, flush=True)


def count_progress(start: float, done: int, total: int, description: str) -> None:
    """A study's progress callback (done, total, description) as plain lines; module-level, so that worker
    processes can be handed it (``functools.partial(count_progress, time.perf_counter())``)."""
    progress_line(f"{done}/{total} {description}", start)


@contextmanager
def progress_status(first: str = "starting"):
    """A ``say(message)`` for the stages of a long command: a live spinner line on a terminal, plain
    time-stamped lines otherwise (a log file gets one line per stage, never spinner frames)."""
    start = time.perf_counter()
    if not console.is_terminal:
        yield lambda message: progress_line(message, start)
        return
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(SpinnerColumn(), TextColumn("{task.description}", markup=False), TimeElapsedColumn(),
                  console=console, transient=True) as bar:
        task = bar.add_task(first, total=None)
        yield lambda message: bar.update(task, description=message)


class StageClock:
    """CPU seconds per stage of a command, from the stage messages it announces (``dualid fit --verbose``):
    a stage lasts from its message to the next one; stages are named by ``key(message)``."""

    def __init__(self, key) -> None:
        self.key, self.times, self.current, self.mark = key, {}, "startup", 0.0
        self.tick("setup")

    def tick(self, message: str) -> None:
        now = time.process_time()
        self.times[self.current] = self.times.get(self.current, 0.0) + now - self.mark
        self.current, self.mark = self.key(message), now

    def line(self) -> str:
        self.tick("")
        self.times.pop("", None)
        total = sum(self.times.values())
        parts = ", ".join(f"{k} {v:.2f}" for k, v in self.times.items())
        return f"CPU time per stage [s]: {parts}; total {total:.2f}"
