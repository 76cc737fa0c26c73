"""The ``tpsv`` command line: a click group of file-to-file subcommands.

Exit status: 0 success, 1 bad data or failed work (one line on stderr, no
traceback), 2 usage error.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass

import click

from .. import __version__
from ..errors import TpsvError


@dataclass
class Settings:
    """Global options, passed to every subcommand through the click context."""

    device: str = "cpu"
    quiet: bool = False


class TpsvFailure(click.ClickException):
    """A TpsvError (or any failure) shown as one line and exit status 1."""

    exit_code = 1

    def show(self, file=None) -> None:
        click.echo(f"tpsv: error: {self.format_message()}", err=True)


class TpsvGroup(click.Group):
    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except (click.exceptions.Exit, click.exceptions.Abort, click.ClickException):
            raise
        except TpsvError as exc:
            raise TpsvFailure(str(exc)) from None
        except MemoryError:
            raise TpsvFailure("out of memory") from None
        except KeyboardInterrupt:
            raise click.exceptions.Abort() from None
        except Exception as exc:  # a bug; still one line unless asked for more
            if os.environ.get("TPSV_DEBUG"):
                raise
            raise TpsvFailure(
                f"internal error: {type(exc).__name__}: {exc} (set TPSV_DEBUG=1 for a traceback)"
            ) from None


@click.group(cls=TpsvGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", prog_name="tpsv")
@click.option(
    "--device",
    default="cpu",
    show_default=True,
    envvar="TPSV_DEVICE",
    help="Warp device for TPS kernels: cpu, cuda or cuda:N (env TPSV_DEVICE).",
)
@click.option("--quiet", "-q", is_flag=True, help="No progress or summaries on stderr.")
@click.pass_context
def main(ctx: click.Context, device: str, quiet: bool) -> None:
    """tpsv: photos to editable, resolution-free vector images (Hermite patches + TPS).

    Each subcommand reads files and writes files; '-' means stdin/stdout where it
    makes sense. Outputs are written atomically.
    """
    ctx.obj = Settings(device=device, quiet=quiet)


def settings(ctx: click.Context) -> Settings:
    """The group's settings (defaults when a command is invoked on its own)."""
    root = ctx.find_root()
    return root.obj if isinstance(root.obj, Settings) else Settings()


def say(ctx: click.Context, message: str) -> None:
    """A human summary line on stderr (suppressed by --quiet)."""
    if not settings(ctx).quiet:
        click.echo(message, err=True)


def progress_enabled(ctx: click.Context) -> bool:
    """Progress bars go to stderr, only on a terminal and without --quiet."""
    return not settings(ctx).quiet and sys.stderr.isatty()


def _register() -> None:
    from . import commands  # noqa: F401  (subcommands attach themselves to `main`)


_register()
