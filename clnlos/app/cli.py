"""The clnlos command line: one entry point, thin over the pipelines.

Known errors (bad file, bad parameter, device problems, kernel build failures) end in one
line on stderr and exit status 2; nothing half-written is left behind. SIGTERM unwinds like
Ctrl-C (temporaries removed, one line) and exits with 128 + 15.
"""

from __future__ import annotations

import argparse
import re
import signal
import sys
import warnings

import pyopencl as cl

from clnlos.version import __version__
from clnlos.app import commands as cli_commands
from clnlos.errors import ClnlosError
from clnlos.io.outputs import Terminated, install_sigterm_cleanup, user_path
from clnlos.runtime.device import list_devices, resolve_device_spec, select_device
from clnlos.runtime.environment import check_environment

EXIT_USAGE = 2


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


def cmd_devices(args) -> int:
    devs = list_devices()
    default = select_device(args.device, args.settings)  # no such device: one-line error
    spec = resolve_device_spec(args.device, args.settings)
    print(f"{'':2}{'P:D':5} {'platform':32} {'device':40} {'version':22} {'CUs':>4} "
          f"{'mem GiB':>8} {'fp64':>5} {'img':>4}")
    for d in devs:
        mark = "*" if default is not None and d.name == default.name.strip() and \
            d.platform == default.platform.name.strip() else " "
        print(f"{mark} {d.spec:5} {d.platform[:32]:32} {d.name[:40]:40} {d.version[:22]:22} "
              f"{d.compute_units:4d} {d.global_mem_bytes / 2**30:8.1f} "
              f"{'yes' if d.fp64 else 'no':>5} {'yes' if d.images else 'no':>4}")
    print(f"* = default device{' for spec ' + repr(spec) if spec else ''} "
          "(set with --device or CLNLOS_DEVICE)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="clnlos", description="GPU-portable OpenCL kernels for non-line-of-sight "
                "imaging through scattering slabs: simulate, reconstruct, study materials.")
    p.add_argument("--version", action="version", version=f"clnlos {__version__}")
    sub = p.add_subparsers(dest="command", parser_class=_Parser, metavar="COMMAND")

    d = sub.add_parser("devices", help="list OpenCL platforms and devices")
    _add_device(d)
    d.set_defaults(func=cmd_devices)

    cli_commands.register(sub, _add_device)
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
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if getattr(args, "func", None) is None:  # bare `clnlos` (or a bare group)
            parser.print_help()
            return 0
        args.settings = check_environment()  # CLNLOS_* read once, passed to the command
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
        if isinstance(exc, cl.MemoryError | cl.LogicError | cl.RuntimeError):
            return _fail(f"OpenCL error: {exc}")
        raise


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
