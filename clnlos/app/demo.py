"""``clnlos demo``: simulate a letters scene (default: the seed's Table 1 round trip, "UT" 0.5 m
behind the 2.54 cm slab), reconstruct it with LCT, f-k and the iterative method, and score each
against the true letters (IoU of the Otsu-thresholded MIP, peak depth)."""

from __future__ import annotations

import importlib.resources
import json
import tomllib
from pathlib import Path

from clnlos.app.flags import add_force
from clnlos.app.reconstruct import reconstruct_to_files
from clnlos.app.simulate import simulate_to_file
from clnlos.config import ReconstructionConfig, load_toml
from clnlos.errors import OutputFileError, ParameterError
from clnlos.forward.scene import Scene
from clnlos.inverse.methods import method_names
from clnlos.io.files import atomic_path, read_capture
from clnlos.io.outputs import check_outputs, stamp
from clnlos.runtime.device import get_queue
from clnlos.study.score.metrics import letters_truth_mask, mip_iou, peak_depth_m


def demo_files() -> tuple[str, ...]:
    """The files the demo writes: the capture, the summary, a volume per registered method."""
    return ("capture.h5", "capture.png", "summary.json") + tuple(
        f"volume_{m}.{ext}" for m in method_names() for ext in ("h5", "png"))


def demo_inputs(scene_path=None, config_path=None):
    """(scene, reconstruction config) of the demo: the given files or the built-in ones."""
    data = importlib.resources.files("clnlos").joinpath("data")
    if scene_path:
        scene = Scene.from_toml(scene_path)
    else:
        text = data.joinpath("demo_scene.toml").read_text()
        scene = Scene.from_dict(tomllib.loads(text), text=text)
    cfg = ReconstructionConfig.from_dict(
        load_toml(config_path) if config_path
        else tomllib.loads(data.joinpath("demo_reconstruct.toml").read_text()))
    if cfg.slab is None:
        cfg = cfg.replace(slab=scene.slab)
    if scene.objects[0].shape != "letters":
        raise ParameterError("objects[0].shape", scene.objects[0].shape,
                             "'letters' (the demo scores letters)")
    return scene, cfg


def run_demo(out_dir, scene, config, *, queue=None, log=print) -> dict:
    """Write the demo's capture, volumes, figures and summary.json into ``out_dir``."""
    queue = get_queue(queue)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sim = simulate_to_file(scene, out / "capture.h5", queue=queue)
    log(f"simulated {sim.capture} ({', '.join(sim.stages)}) in {sim.seconds:.2f} s")
    obj = scene.objects[0]
    truth = letters_truth_mask(obj.text, obj.height_m, obj.stroke_m, obj.translate_m[:2],
                               scene.scan_centres())
    summary = {"device": queue.device.name.strip(), "simulate_s": sim.seconds,
               "stages": sim.stages, "methods": {}}
    capture = read_capture(sim.capture)
    for method in method_names():
        cfg = config.replace(method=method).validate()
        vol_path = out / f"volume_{method}.h5"
        rec = reconstruct_to_files(capture, vol_path, cfg, queue=queue,
                                   title_extra=f"demo: {obj.text} at {obj.translate_m[2]} m")
        score, _ = mip_iou(rec.volume, truth)
        depth = peak_depth_m(rec.volume, rec.extents["voxel_depth_m"])
        seconds = sum(rec.timings_s.values())
        summary["methods"][method] = {"iou": score, "depth_m": depth, "reconstruct_s": seconds}
        log(f"{method}: IoU of the thresholded MIP with the true letters {score:.3f}, "
            f"depth {depth:.3f} m (true {obj.translate_m[2]} m), {seconds:.2f} s; wrote "
            f"{vol_path} and .png")
    with atomic_path(out / "summary.json") as tmp:
        tmp.write_text(json.dumps(stamp(summary), indent=1))
    log(f"wrote {out / 'summary.json'}")
    return summary


def cmd_demo(args) -> int:
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise OutputFileError(f"-o {out}: is a file; the demo writes a folder")
    scene, cfg = demo_inputs(args.scene, args.config)
    outs = {f"-o {name}": out / name for name in demo_files()}
    check_outputs(outs, inputs=[args.scene, args.config, *scene.input_paths()],
                  implied=dict.fromkeys(outs), force=args.force)
    run_demo(out, scene, cfg, queue=get_queue(args.device, settings=args.settings))
    return 0


def demo_arguments(d, add_device) -> None:
    """The arguments of ``clnlos demo`` on the parser ``d``."""
    d.add_argument("-o", "--output", default="out/demo",
                   help="output folder (default %(default)s)")
    d.add_argument("--scene", help="scene TOML with letters as objects[0] (default: built-in)")
    d.add_argument("--config", help="reconstruction TOML (default: built-in; its slab "
                   "defaults to the scene's)")
    add_force(d)
    add_device(d)
    d.set_defaults(func=cmd_demo)
