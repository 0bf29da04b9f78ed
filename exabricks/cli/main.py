"""The `exabricks` click group and the one place where errors become exit statuses."""
# ruff: noqa: E402 (run as a program, the signal handlers go in before the imports)

from __future__ import annotations

from ..util import interrupt

if __name__ == "__main__":  # python -m exabricks.cli.main: signals held from here to main()
    interrupt.install(hold=True)

import logging
import os
import sys
import warnings

import click

from ..util.version import __version__
from ..util.errors import ExabricksError, one_line

COMMANDS = (
    "ingest",
    "coarsen",
    "brick",
    "regions",
    "bvh",
    "join",
    "values",
    "surface",
    "render",
    "probe",
    "compare",
    "movie",
    "series",
    "info",
    "devices",
    "camera",
    "cache",
    "view",
)


class LazyGroup(click.Group):
    """Imports a command's module only when it runs (keeps `--help` and `info` fast)."""

    def list_commands(self, ctx):
        return [c for c in COMMANDS if self._module(c) is not None]

    def get_command(self, ctx, name):
        module = self._module(name)
        return getattr(module, name.replace("-", "_"), None) if module else None

    @staticmethod
    def _module(name):
        import importlib

        try:
            return importlib.import_module(f"exabricks.cli.{name.replace('-', '_')}")
        except ModuleNotFoundError as e:
            if e.name == f"exabricks.cli.{name}":
                return None
            raise


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="exabricks")
@click.option("-v", "--verbose", count=True, help="More log output (repeatable).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors; no progress bars.")
@click.option("--debug", is_flag=True, envvar="EXABRICKS_DEBUG",
              help="Show Python tracebacks (also EXABRICKS_DEBUG=1).")
@click.pass_context
def cli(ctx, verbose, quiet, debug):
    """Render adaptive-mesh-refinement data with the ExaBricks method.

    Stages chain through versioned .npz files:
    ingest -> brick -> regions -> bvh -> render / probe.
    """
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    logging.basicConfig(level=level, format="%(message)s", stream=sys.stderr)
    ctx.obj = {"quiet": quiet, "debug": debug}
    if quiet:
        os.environ["EXABRICKS_QUIET"] = "1"


def _fail(message: str, status: int = 1, shared: bool = False) -> None:
    """Print `error: message` and exit with `status`. Under MPI only rank 0 speaks
    for an error every rank shares (`shared`: exabricks.parallel.AgreedError, a
    signal from the launcher, or any before MPI started); a rank's own error
    afterwards is printed and ends the whole job."""
    from .. import parallel

    agreed = shared or not parallel.initialized()
    rank = parallel.launched_rank()
    if rank == 0 or not agreed:
        prefix = f"rank {rank}: " if not agreed else ""
        click.echo(f"error: {prefix}{one_line(message)}", err=True)
    if not agreed:
        sys.stderr.flush()
        parallel.abort_world(status)
    sys.exit(status)


def main(argv=None) -> None:
    """Console entry point: exit 0 on success, 1 on bad data or failure, 2 on bad usage,
    128 + N when signal N (SIGTERM, SIGHUP, SIGINT) ended the run."""
    debug = os.environ.get("EXABRICKS_DEBUG", "") not in ("", "0") or "--debug" in (
        argv if argv is not None else sys.argv[1:]
    )
    if not debug:
        # numpy's RuntimeWarnings (overflow, invalid value) would precede the one
        # `error:` line; every condition that matters is checked and named instead.
        warnings.simplefilter("ignore", RuntimeWarning)
    try:
        try:
            interrupt.install()
            # Without standalone mode click *returns* the status of ctx.exit(N) instead of raising.
            status = cli.main(args=argv, prog_name="exabricks", standalone_mode=False)
            interrupt.raise_pending()
        finally:
            # The outcome is decided: a signal from here on neither kills the process
            # nor changes its status (docs/design.md, "Signals").
            interrupt.ignore()
    except interrupt.Interrupted as e:
        _fail(f"interrupted ({signal_name(e.signum)})", e.exit_status, shared=True)
    except (KeyboardInterrupt, click.exceptions.Abort):
        _fail("interrupted (SIGINT)", 128 + 2, shared=True)
    except click.exceptions.Exit as e:
        sys.exit(e.exit_code)
    except click.ClickException as e:
        from .. import parallel

        if parallel.launched_rank() == 0:  # every rank parses the same command line
            click.echo(f"error: {usage_line(e)}", err=True)
        sys.exit(e.exit_code)
    except ExabricksError as e:
        if debug:
            raise
        from .. import parallel

        _fail(str(e), shared=isinstance(e, parallel.AgreedError))
    except MemoryError:
        if debug:
            raise
        _fail("out of memory")
    except RecursionError:
        if debug:
            raise
        _fail("input nested too deeply (a JSON file or header with thousands of levels?)")
    except Exception as e:  # the last line of defence: one line, no traceback
        if debug:
            raise
        _fail(f"internal error: {type(e).__name__}: {e} (rerun with --debug for a traceback)")
    sys.exit(status if isinstance(status, int) else 0)


def usage_line(e: click.ClickException) -> str:
    """A usage error as one line: click's message (with its "Did you mean" hint)
    and, for a command's usage, where its help is; click's own form takes three
    lines (usage, "Try --help", the error)."""
    message = one_line(e.format_message())
    ctx = getattr(e, "ctx", None)
    if isinstance(e, click.UsageError) and ctx is not None:
        message += f" (see {ctx.command_path} --help)"
    return message


def signal_name(signum: int) -> str:
    import signal

    return signal.Signals(signum).name


if __name__ == "__main__":
    main()
