"""The ``spotlights`` command line: a thin layer over the library.

Each command group lives in its own module exposing ``register(subparsers)``;
the modules import the library at their top, but none of its heavy optional
dependencies (torch, matplotlib, plotly, pyarrow, ray, onnx are imported inside
the handlers that need them), so ``spotlights --help`` loads no torch.

Handlers return an exit code (0 on success). Any :class:`SpotlightsError`
becomes one line on stderr and its exit code (2 the input's fault, 1 a helper process that failed), an
optional package that is not installed one line naming its extra (2); no traceback is shown.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from .. import logs
from .._version import __version__
from ..errors import SpotlightsError, missing_extra
from ..options import join_axis_values, option_names
from ..outputs import os_error_line
from ..processes import forget_interrupt, in_main_thread, sigint_held
from ._util import add_options  # noqa: F401 - the one way a command adds its options (option() fields)

# One line per command group; a new group is one module and one line here.
COMMAND_MODULES = [
    "spotlights.cli.core",  # encode, decode, show
    "spotlights.cli.demo",  # demo
    "spotlights.cli.dataset",  # dataset build, info, export, show
    "spotlights.cli.real",  # real extract, evaluate, show
    "spotlights.cli.analyze",  # analyze density
    "spotlights.cli.study",  # study rigs
    "spotlights.cli.learn",  # train, evaluate, bench models
    "spotlights.cli.complete",  # complete (a frame with its boxes, or one object)
    "spotlights.cli.reproduce",  # reproduce (the paper's tables)
    "spotlights.cli.view",  # view (interactive HTML page)
    "spotlights.cli.track",  # track (a detector's boxes -> tracks)
]

EPILOG = """\
start here:
  spotlights demo --out out/demo                    # the whole pipeline on bundled CC0 data, with pictures

the representation:
  spotlights encode car.ply --out car.npz           # mesh -> Spotlights depth array (32 x 64 rays, 60 deg)
  spotlights decode car.npz --out car_points.ply    # depth array -> ordered point cloud
  spotlights show car.npz --out car.png             # look at it
  spotlights view car.npz car.ply --out view.html   # interactive 3-D page, opens offline (rotate, zoom)

completion:
  spotlights complete scan.bin --boxes boxes.json --out done.ply --show done.png   # a LiDAR frame + its 3-D boxes
  spotlights dataset build --meshes DIR --out cars.h5                          # simulated LiDAR dataset
  spotlights train --model sanet --data cars.h5 --schedule cpu                 # SA-Net or a baseline
  spotlights evaluate --data cars.h5 --checkpoint runs/sanet/best.pt           # Table 1
  spotlights real extract DIR --format av2 --out av2.h5                        # real LiDAR (KITTI, AV2, ...)

Run 'spotlights COMMAND --help' for the options and an example of each command.
"""


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors exit with code 2 and one clear line."""

    def error(self, message: str):  # noqa: D401 - argparse API
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message}\n")

    def parse_known_args(self, args=None, namespace=None):  # noqa: D401 - argparse API
        """As argparse's, with ``--up -z`` read as ``--up=-z`` (:func:`spotlights.options.join_axis_values`)."""
        args = sys.argv[1:] if args is None else [str(a) for a in args]
        return super().parse_known_args(join_axis_values(args), namespace)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="spotlights",
        description="Spotlights: represent shapes as depth arrays probed from spherical viewpoints, "
        "build completion datasets, train and evaluate SA-Net and its baselines.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"spotlights {__version__}")
    parser.add_argument(
        "-v",
        "--verbose",
        action="count",
        default=0,
        help="log what the library does on stderr (-v: info lines, -vv: debug); by default warnings only",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    for leaf in _commands(parser):  # -v after the command as well: spotlights real complete ... -v
        leaf.add_argument(
            "-v",
            "--verbose",
            action="count",
            default=argparse.SUPPRESS,
            help="log what the library does on stderr (-v: info lines, -vv: debug), as `spotlights -v COMMAND` does",
        )
    return parser


def _commands(parser: argparse.ArgumentParser):
    """The parsers of every command (the leaves below the sub-command groups), in registration order."""
    groups = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]  # noqa: SLF001 - argparse's
    if not groups:
        yield parser
    for group in groups:
        seen: set[int] = set()
        for child in group.choices.values():  # a command's aliases name one parser
            if id(child) not in seen:
                seen.add(id(child))
                yield from _commands(child)


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived: unwinds like Ctrl-C (pools stopped, temporaries removed), exit code 143."""


def _on_sigterm(signum, frame):
    raise Terminated()


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns the exit code.

    0 success; 2 a user error (bad file, bad parameter, an output that cannot be written: one
    line on stderr naming the file or parameter, no traceback; argparse's usage errors keep
    their usage block); 1 a :class:`~spotlights.errors.ProcessFailure` (a helper process died or
    hung: one line, no traceback); 130 Ctrl-C; 143 SIGTERM. ``-q`` silences stdout (summary lines) as
    well as progress bars; warnings and errors still go to stderr.
    """
    import contextlib
    import os
    import signal

    previous = None
    parser: argparse.ArgumentParser | None = None
    try:  # from the first line on: a Ctrl-C while the arguments are parsed is 130 and one line too
        with sigint_held():  # imports every command's module (C extensions may turn a Ctrl-C into an ImportError)
            parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 0 if args.command is None else 2
        if in_main_thread():
            previous = signal.signal(signal.SIGTERM, _on_sigterm)
        with contextlib.ExitStack() as stack:
            args = _with_config_file(parser, args, argv)
            stack.callback(logs.LOGGER.setLevel, logs.LOGGER.level)  # the level as it was, after the command
            stack.callback(
                logs.LOGGER.removeHandler, logs.configure(0 if getattr(args, "quiet", False) else args.verbose)
            )
            if getattr(args, "quiet", False):
                stack.enter_context(contextlib.redirect_stdout(stack.enter_context(open(os.devnull, "w"))))
            return int(args.func(args) or 0)
    except SpotlightsError as exc:
        print(f"spotlights: error: {option_names(exc, parser) if parser else exc}", file=sys.stderr)
        return exc.exit_code
    except Terminated:
        print("spotlights: terminated", file=sys.stderr)
        forget_interrupt()
        return 143
    except KeyboardInterrupt:
        return _interrupted()
    except BrokenPipeError:
        return 0
    except ModuleNotFoundError as exc:  # an optional extra that is not installed: which one, in one line
        line = missing_extra(exc)
        if line is None:
            raise
        print(f"spotlights: error: {line}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file the command reads or writes: one line, naming it
        print(f"spotlights: error: {os_error_line(exc)}", file=sys.stderr)
        return 2
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _interrupted() -> int:
    """Ctrl-C: one line on stderr, exit code 130."""
    print("spotlights: interrupted", file=sys.stderr)
    forget_interrupt()
    return 130


def _with_config_file(parser: argparse.ArgumentParser, args: argparse.Namespace, argv) -> argparse.Namespace:
    """A command that reads options from a YAML (``dataset build --config``): parse ``argv`` again
    with the file's values as the command's defaults, so that the command line wins."""
    reader = getattr(args, "config_reader", None)
    if reader is None or not args.config:
        return args
    args.command_parser.set_defaults(**reader(args.config))
    return parser.parse_args(argv)
