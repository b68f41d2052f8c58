"""Forward simulation composed from a scene: only the effects the scene asks for are built.

    I   = LightCone(elements)                 always   (kernels/lightcone.cl)
    tau = (Phi * Phi) * I                     [slab]   (forward.blur, physical units; I is
                                                        computed on the scan grid widened by
                                                        the blur's lateral reach, then cropped)
    tau = g_pulse * tau                       [laser] pulse_width_s (kernels/temporal.cl)
    N   ~ Poisson(eta tau + dark)             [detector] (numpy Generator seeded by `seed`)

Units: I and tau in 1/(m^2 sr) per bin (the light-cone normalisation of transient renderers:
albedo f_r cos^2 cos^2 / r^4 dA summed per bin); with a detector, photon counts, where
eta = photons emitted x efficiency x etendue (m^2 sr) and dark = rate x exposure x
bin width x repetition rate per bin.

With ``[transport] model = "bistatic"`` (or "auto" choosing it) the light cone and the slab
blur are one stage, the seed's Eq. 8 in full (:mod:`clnlos.forward.bistatic`, kernels/bistatic.cl):
light leaves the slab's face at r1 != r2, with the full BRDF f(w1, w2); its stage is named
``lightcone:bistatic(rings=..,angles=..,texture=..)`` and no ``slab_blur`` follows.

The model is a chain of stages built from the scene (:func:`build_stages`), each with a
``name`` (recorded in the capture's ``stages`` when ``recorded``) and ``__call__``: the
transport (samples -> device transient), the slab blur and the pulse (linear operators on
the device transient), the readout (device -> host, the blur's margin cropped) and the
photon noise (host). ``run`` applies them in order.

Left out: occlusion between elements (no visibility test), interreflections.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from clnlos.config import slab_table
from clnlos.errors import ParameterError
from clnlos.forward.bistatic import (
    BistaticTransport,
    auto_choice,
    face_quadrature,
    scene_textures,
    texture_label,
)
from clnlos.forward.blur import blur_margin, forward_blur
from clnlos.forward.lightcone import LightCone
from clnlos.forward.noise import PhotonNoise
from clnlos.forward.pulse import PulseBlur
from clnlos.forward.sampling import (
    SurfaceSamples,
    check_scene_geometry,
    check_scene_size,
    sample_scene,
)
from clnlos.forward.scene import Scene
from clnlos.io.capture import Capture
from clnlos.runtime.device import get_queue, require_dtype


@dataclass
class Stage:
    """One step of the chain: ``apply(x) -> y`` named ``name`` (recorded in a capture's
    ``stages`` when ``recorded``); ``operator`` is the plan object behind it."""

    name: str
    apply: Any
    operator: Any = None
    recorded: bool = True

    def __call__(self, x):
        return self.apply(x)


@dataclass
class Readout:
    """Device transient -> host array [t, y, x]: the lateral margin cropped, FFT round-off
    (-1e-17 where tau is 0) clipped; an all-zero capture is an error naming the objects.
    The scene's geometry ``notes`` are issued as warnings once a capture is known not to be
    all zero (a run that ends in that error says one line, not a warning and an error)."""

    scene: Scene
    margin: int = 0
    notes: list = field(default_factory=list)

    def __call__(self, x_g) -> np.ndarray:
        tau = x_g.get()
        if self.margin:
            m = self.margin
            tau = tau[:, m:-m, m:-m]
        tau = np.maximum(tau, 0)
        if not np.any(tau):  # what check_scene_geometry cannot see (a black material, ...)
            s = self.scene
            raise ParameterError("objects", f"{len(s.objects)} object(s)", "objects that "
                                 "return light to the scan points inside the time window "
                                 f"[{s.start_s:.3g}, {s.start_s + s.bins * s.bin_width_s:.3g})"
                                 " s: this scene's capture is all zero (check the objects' "
                                 "materials, rotations and positions)")
        for note in self.notes:
            warnings.warn(note, UserWarning, stacklevel=3)
        self.notes = []  # once per model
        return tau


def transport_model(scene: Scene, samples: SurfaceSamples, queue) -> tuple[str, str]:
    """The scene's ``[transport] model``, "auto" resolved (:func:`clnlos.forward.bistatic.
    auto_choice`): ("confocal" or "bistatic", why)."""
    model = scene.transport.model
    if model != "auto":
        return model, "requested"
    if scene.slab is None:
        return "confocal", "auto: no slab"
    quad = face_quadrature(scene.slab, bins=scene.bins, bin_width_s=scene.bin_width_s, rings=1,
                           angles=1, n_dipoles=scene.n_dipoles, queue=queue)
    choice, why = auto_choice(scene, samples, quad.rms_m)
    return choice, f"auto: {why}"


def check_slab_window(scene: Scene) -> None:
    if scene.start_s != 0:
        raise ParameterError("time.start_s", scene.start_s,
                             "0 when a [slab] is given (the slab blur is causal from t = 0)")


@dataclass
class TransportStages:
    """What a transport contributes: its stages, the lateral margin the readout crops and
    whether the blur's reach is covered by it."""

    stages: list[Stage]
    margin: int = 0
    reach_covered: bool = True
    shape: tuple = field(default_factory=tuple)


def bistatic_stages(scene: Scene, samples: SurfaceSamples, dtype, queue) -> TransportStages:
    """Eq. 8 (:mod:`clnlos.forward.bistatic`): one stage carries the light through the slab
    and back (no lateral grid: every face sample is evaluated exactly)."""
    s, t = scene, scene.transport
    if s.slab is None:
        raise ParameterError("transport.model", "bistatic", "'confocal' or 'auto' without "
                             "a [slab]")
    check_slab_window(s)
    op = BistaticTransport(
        slab=s.slab, points=s.points, width_m=s.width_m, bins=s.bins,
        bin_width_s=s.bin_width_s, start_s=s.start_s, textures=scene_textures(s, t),
        rings=t.face_rings, angles=t.face_angles, n_dipoles=s.n_dipoles,
        splat_order=s.splat_order, dtype=dtype, queue=queue,
        texture_label=texture_label(s, t))
    return TransportStages([Stage(op.stage, op, op)], 0, True, op.shape)


def confocal_stages(scene: Scene, samples: SurfaceSamples, dtype, queue) -> TransportStages:
    """Eq. 9: the confocal light cone, then the slab blur Phi * Phi when there is a slab.

    Light diffuses through the slab sideways: a scan point also sees the hidden-side
    transient I up to the blur's reach outside the scanned square, so I is computed on a
    grid widened by that many cells per side (cell centres kept) and cropped after the blur
    (:func:`clnlos.forward.blur.blur_margin`); a capped margin makes the blur pad instead
    of wrap."""
    s = scene
    margin, covered = 0, False
    if s.slab is not None:
        margin, covered = blur_margin(s.slab, s.bins * s.bin_width_s, s.pitch_m, s.points,
                                      s.blur_reach_tol, s.n_dipoles, queue)
    n_ext = s.points + 2 * margin
    grid = f"the transient of time.bins = {s.bins} x scan.points = {s.points}^2"
    if margin:
        grid += (f" (computed on {n_ext} x {n_ext} points: the slab blur reaches "
                 f"{margin} scan cells past each side)")
    cone = LightCone(points=n_ext, width_m=n_ext * s.pitch_m, bins=s.bins,
                     bin_width_s=s.bin_width_s, start_s=s.start_s,
                     retro=samples.retro_tables is not None,
                     cone=samples.cone_tables is not None, splat_order=s.splat_order,
                     dtype=dtype, queue=queue, describe=grid)
    kind = ("retroreflective" if samples.cone_tables is not None else "brdf-table"
            if samples.retro_tables is not None else "lambertian")
    stages = [Stage(f"lightcone:{kind}", cone, cone)]
    if s.slab is not None:
        check_slab_window(s)
        blur = forward_blur(s.slab, cone.shape, s.bin_width_s, s.pitch_m, s.n_dipoles,
                            covered, np.dtype(dtype).str, queue)
        stages.append(Stage("slab_blur", blur, blur))
    return TransportStages(stages, margin, covered, cone.shape)


TRANSPORTS = {"confocal": confocal_stages, "bistatic": bistatic_stages}


def build_stages(scene: Scene, samples: SurfaceSamples, transport: str, dtype, queue,
                 notes=()) -> tuple[list[Stage], TransportStages]:
    """The chain a scene asks for: its transport (and slab blur), the pulse when the laser
    has a width, the readout, the photon noise when there is a detector."""
    tr = TRANSPORTS[transport](scene, samples, dtype, queue)
    stages = list(tr.stages)
    if scene.pulse_width_s is not None:
        pulse = PulseBlur(tr.shape, scene.pulse_width_s, scene.bin_width_s, dtype, queue)
        stages.append(Stage("pulse_blur", pulse, pulse))
    stages.append(Stage("readout", Readout(scene, tr.margin, list(notes)), recorded=False))
    if scene.detector is not None:
        noise = PhotonNoise.of_scene(scene)
        stages.append(Stage("photon_noise", noise, noise))
    return stages, tr


class ForwardModel:
    """The stages a scene asks for, built once; ``run()`` returns the capture [t, y, x]."""

    def __init__(self, scene: Scene, *, dtype=np.float32, queue=None):
        self.scene = scene
        self.queue = get_queue(queue)
        self.dtype = require_dtype(self.queue.device, dtype)
        check_scene_size(scene, self.queue.device, self.dtype)
        self.warnings = check_scene_geometry(scene, emit=False)  # issued by the readout
        self.samples = sample_scene(scene)
        self.transport, self.transport_reason = transport_model(scene, self.samples,
                                                                self.queue)
        self.chain, tr = build_stages(scene, self.samples, self.transport, self.dtype,
                                      self.queue, self.warnings)
        self.margin, self.reach_covered = tr.margin, tr.reach_covered
        self.lightcone = self.chain[0].operator
        self.stages = [st.name for st in self.chain if st.recorded]

    def stage(self, name: str):
        """The operator of the stage ``name`` (None when the scene has no such stage)."""
        return next((st.operator for st in self.chain if st.name == name), None)

    @property
    def blur(self):
        return self.stage("slab_blur")

    @property
    def pulse(self):
        return self.stage("pulse_blur")

    def setup_attrs(self) -> dict:
        """What a capture of this model records about its setup (see io.capture.Capture)."""
        s = self.scene
        a = {"scene": s.text, "stages": json.dumps(self.stages),
             "elements": len(self.samples.elements),
             "transport": json.dumps({"model": self.transport,
                                      "reason": self.transport_reason})}
        if s.slab is not None:
            t = slab_table(s.slab)
            if s.n_dipoles is not None:
                t["n_dipoles"] = s.n_dipoles
            a["slab"] = json.dumps(t)
        if s.pulse_width_s is not None:
            a["pulse_width_s"] = s.pulse_width_s
        return a

    def capture(self) -> Capture:
        """Run the model and return the capture with its recorded setup."""
        s = self.scene
        return Capture(self.run(), s.bin_width_s, s.start_s, s.width_m, "simulated",
                       self.setup_attrs())

    def run(self, progress=None) -> np.ndarray:
        """The capture [t, y, x] float32; ``progress(stage)`` is called as each recorded
        stage finishes."""
        x = self.samples
        for st in self.chain:
            x = st(x)
            if progress is not None and st.recorded:
                self.queue.finish()
                progress(st.name)
        return np.asarray(x).astype(np.float32)
