"""The clnlos command line: one entry point, thin over the pipelines.

Known errors (bad file, bad parameter, device problems, kernel build failures) end in one
line on stderr and exit status 2; nothing half-written is left behind. SIGTERM unwinds like
Ctrl-C (temporaries removed, one line) and exits with 128 + 15.
"""

from __future__ import annotations

import argparse
import importlib
import re
import signal
import sys
import warnings

from clnlos.errors import ClnlosError
from clnlos.io.outputs import Terminated, install_sigterm_cleanup, user_path
from clnlos.version import __version__

EXIT_USAGE = 2
ENVIRONMENT = "clnlos.runtime.environment"  # check_environment, before any command's work

# sub-command -> (module, its function adding the command's arguments, one-line help). A
# command's module is imported by name (importlib) only when that command runs or the whole
# parser is built (tests, --help of every command): `clnlos --version` loads none of them and
# `clnlos reconstruct` neither the study, the bench nor the BRDF fits -- a plugin table like
# clnlos.inverse.methods, which the import graph does not show
COMMANDS = {
    "devices": ("clnlos.app.devices_command", "devices_arguments",
                "list OpenCL platforms and devices"),
    "reconstruct": ("clnlos.app.commands", "reconstruct_arguments",
                    "reconstruct a hidden volume from a capture"),
    "plot": ("clnlos.app.commands", "plot_arguments",
             "re-render the figure of a reconstructed volume"),
    "simulate": ("clnlos.app.commands", "simulate_arguments",
                 "simulate a confocal capture from a scene TOML"),
    "demo": ("clnlos.app.demo", "demo_arguments",
             "simulate 'UT' behind the slab, reconstruct with LCT, f-k and the iterative "
             "method, score"),
    "brdf": ("clnlos.app.brdf_command", "brdf_arguments",
             "fit, tabulate and plot BRDF models"),
    "study": ("clnlos.app.study_command", "study_arguments", "the material study (main job)"),
    "legibility": ("clnlos.app.legibility_command", "legibility_arguments",
                   "P(legible) [interval] of captures or reconstructions by the judge "
                   "shipped with clnlos (or a study's: --model)"),
    "bench": ("clnlos.app.bench_command", "bench_arguments",
              "accuracy versus time of every kernel knob (bench.json, bench.html)"),
}


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors as one line with exit status 2 (no usage dump), and reads
    negative numbers in any float notation (``--bin-width -1e-12``) as values, so that the
    value's own check names the flag."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self._negative_number_matcher = re.compile(
            r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|nan)$", re.IGNORECASE)

    def error(self, message):
        # a sub-command's parser names itself ("clnlos reconstruct: argument --method ...");
        # the top-level one needs no second "clnlos:"
        where = self.prog.split(" ", 1)[1] + ": " if " " in self.prog else ""
        raise SystemExit(_fail(f"{where}{message}"))


def _fail(msg: str) -> int:
    first = msg.strip().splitlines()
    print(f"clnlos: error: {first[0] if first else msg}", file=sys.stderr)
    rest = first[1:]
    if rest:  # build logs and the like: kept, but after the one-line message
        print("\n".join(rest), file=sys.stderr)
    return EXIT_USAGE


def _add_device(p: argparse.ArgumentParser) -> None:
    p.add_argument("--device", default=None,
                   help="OpenCL device: P:D, a name such as pocl or nvidia[:K], cpu or gpu "
                        "(default: $CLNLOS_DEVICE, else the first GPU, else the first device)")


def command_named(argv: list[str]) -> str | None:
    """The sub-command an argument list runs: its first word that is not an option (the
    top level has no option taking a value), None for none (``--version``, ``--help``)."""
    return next((a for a in argv if not a.startswith("-")), None)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser with every sub-command's help; the arguments of the command named ``only``
    alone when given (of none for a name that is no command's), else of every command."""
    p = _Parser(prog="clnlos", description="GPU-portable OpenCL kernels for non-line-of-sight "
                "imaging through scattering slabs: simulate, reconstruct, study materials.")
    p.add_argument("--version", action="version", version=f"clnlos {__version__}")
    sub = p.add_subparsers(dest="command", parser_class=_Parser, metavar="COMMAND")

    for name, (module, arguments, help_) in COMMANDS.items():
        c = sub.add_parser(name, help=help_)
        if only is None or only == name:
            getattr(importlib.import_module(module), arguments)(c, _add_device)
    return p


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    """Warnings a user should see, as one line each (no source location)."""
    print(f"clnlos: warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    warnings.showwarning = _one_line_warning
    previous = install_sigterm_cleanup()
    try:
        return _main(argv)
    finally:
        if previous is not None:  # main() called in-process (tests): restore the handler
            signal.signal(signal.SIGTERM, previous)


def _main(argv: list[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(only=command_named(argv) or "")  # "": no command's arguments
    try:
        args = parser.parse_args(argv)
        if getattr(args, "func", None) is None:  # bare `clnlos` (or a bare group)
            parser.print_help()
            return 0
        # CLNLOS_* read once, passed to the command (the checks load the FFT backends)
        args.settings = importlib.import_module(ENVIRONMENT).check_environment()
        return int(args.func(args) or 0)
    except SystemExit as exc:
        return int(exc.code) if isinstance(exc.code, int) else EXIT_USAGE
    except ClnlosError as exc:
        return _fail(str(exc))
    except Terminated as exc:
        _fail(str(exc))
        return 128 + exc.signum
    except KeyboardInterrupt:  # Ctrl-C: the shell's convention, 128 + SIGINT
        _fail("interrupted")
        return 128 + signal.SIGINT
    except MemoryError:
        return _fail("out of host memory: use a smaller grid")
    except OSError as exc:  # files a user named: permissions, full disk, ...
        name = user_path(getattr(exc, "filename", None))  # never a hidden temporary
        where = f"{name}: " if name else ""
        return _fail(f"{where}{(str(exc.strerror or exc).splitlines() or [''])[0]}")
    except Exception as exc:  # OpenCL runtime errors a user can cause (device memory, ...)
        cl = sys.modules.get("pyopencl")  # not loaded: no OpenCL error can have happened
        if cl is not None and isinstance(exc, cl.MemoryError | cl.LogicError | cl.RuntimeError):
            return _fail(f"OpenCL error: {exc}")
        raise


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
