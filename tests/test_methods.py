"""The inversion contract and its registry (clnlos.inverse.methods): every method has the same
constructor, the config, CLI and demo read the one table, and a method registered there is
all the pipeline needs."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from clnlos import config as config_mod
from clnlos.app.cli import build_parser
from clnlos.config import ReconstructionConfig
from clnlos.inverse import methods
from clnlos.inverse.methods import Inversion, MethodEntry, method_class
from clnlos.inverse.pipeline import reconstruct
from clnlos.io.capture import Capture


def test_every_method_has_the_one_constructor():
    base = inspect.signature(Inversion.__init__)
    for name in methods.METHODS:
        cls = method_class(name)
        assert issubclass(cls, Inversion) and cls.name == name
        assert inspect.signature(cls.__init__).parameters.keys() == base.parameters.keys()


def test_every_method_configures_through_the_one_signature():
    base = inspect.signature(Inversion.configure)
    for name in methods.METHODS:
        sig = inspect.signature(method_class(name).configure)
        assert sig.parameters.keys() == base.parameters.keys(), name


def test_config_and_cli_read_the_registry(monkeypatch):
    assert config_mod.METHOD_FALLOFF == {m: e.falloff for m, e in methods.METHODS.items()
                                         if e.falloff is not None}
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")  # argparse's own API
    for cmd in ("reconstruct", "study"):
        method = next(a for a in sub.choices[cmd]._actions if a.dest == "method")
        assert tuple(method.choices) == tuple(methods.METHODS)
    # a method registered later is offered by a parser built later and accepted by the config
    monkeypatch.setitem(methods.METHODS, "time_as_depth",
                        MethodEntry(__name__, "TimeAsDepth", None, "test"))
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    method = next(a for a in sub.choices["reconstruct"]._actions if a.dest == "method")
    assert "time_as_depth" in method.choices
    assert ReconstructionConfig(method="time_as_depth").validate().method == "time_as_depth"


class TimeAsDepth(Inversion):
    """A trivial method for the test: the (deconvolved) transient itself as the volume."""

    name = "time_as_depth"

    def configure(self, tau_g, noise, rule_snr, timed, probe=None, slab_influence=None):
        return {"time_as_depth": True}

    def __call__(self, tau_g, *, progress=None, setup=None):
        return tau_g.copy()


def test_a_registered_method_is_all_the_pipeline_needs(queue, monkeypatch):
    monkeypatch.setitem(methods.METHODS, "time_as_depth",
                        MethodEntry(__name__, "TimeAsDepth", None, "test"))
    rng = np.random.default_rng(3)
    tau = rng.random((64, 4, 4)).astype(np.float32)
    cap = Capture(tau, 40e-12, 0.0, 0.2, "test")
    rec = reconstruct(cap, ReconstructionConfig(method="time_as_depth").validate(),
                      device=queue)
    assert rec.stages[-1] == "invert:time_as_depth" and rec.params["time_as_depth"]
    np.testing.assert_allclose(rec.volume, tau / tau.max(), rtol=1e-6)


def test_an_unregistered_method_is_refused_by_the_config():
    from clnlos.errors import ParameterError

    with pytest.raises(ParameterError, match="method"):
        ReconstructionConfig(method="no_such_method").validate()
