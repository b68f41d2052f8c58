"""``clnlos devices``: the OpenCL platforms and devices, the default one marked."""

from __future__ import annotations

from clnlos.runtime.device import list_devices, resolve_device_spec, select_device


def cmd_devices(args) -> int:
    """The devices, the default one marked."""
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


def devices_arguments(d, add_device) -> None:
    """The arguments of ``clnlos devices`` on the parser ``d``."""
    add_device(d)
    d.set_defaults(func=cmd_devices)
