"""The type stubs say what the module does: every function's parameters, in order, with the
defaults the module uses (those the module takes from the library are checked against the
parameters a stage records)."""

import ast
import inspect
from pathlib import Path

import photonkit
import pytest

from conftest import SAMPLES

STUB = ast.parse((Path(photonkit.__file__).parent / "__init__.pyi").read_text())
FUNCTIONS = {f.name: f for f in STUB.body if isinstance(f, ast.FunctionDef)}


def stub_parameters(f):
    """(name, keyword-only, default or inspect.Parameter.empty) of a stub's parameters."""
    a = f.args
    positional = a.posonlyargs + a.args
    defaults = [inspect.Parameter.empty] * (len(positional) - len(a.defaults)) + list(a.defaults)
    out = [(p.arg, False, d) for p, d in zip(positional, defaults)]
    out += [(p.arg, True, d if d is not None else inspect.Parameter.empty) for p, d in zip(a.kwonlyargs, a.kw_defaults)]
    return [(n, k, d if d is inspect.Parameter.empty else ast.literal_eval(d)) for n, k, d in out]


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_each_function_has_the_stubs_signature(name):
    runtime = inspect.signature(getattr(photonkit, name))
    got = [
        (p.name, p.kind == p.KEYWORD_ONLY, p.default) for p in runtime.parameters.values()
    ]
    want = stub_parameters(FUNCTIONS[name])
    assert [(n, k) for n, k, _ in got] == [(n, k) for n, k, _ in want]
    for (n, _, have), (_, _, stub) in zip(got, want):
        if have is not Ellipsis:  # a default the module takes from the library: checked below
            assert have == stub, n


def test_every_export_is_in_the_stubs():
    names = {n.id for n in ast.walk(STUB) if isinstance(n, ast.Name)} | set(FUNCTIONS)
    names |= {c.name for c in STUB.body if isinstance(c, ast.ClassDef)}
    assert set(photonkit.__all__) <= names


def test_the_library_defaults_are_the_stubs():
    detected = photonkit.detect(SAMPLES / "collimated-cusp.phm")
    recorded = detected.history[-1]["parameters"]
    stub = {n: d for n, _, d in stub_parameters(FUNCTIONS["detect"])}
    for key in ["kc", "beta", "growths", "gain"]:
        assert recorded[key] == pytest.approx(stub[key]), key
    relaxed = photonkit.relax(detected)
    recorded = relaxed.history[-1]["parameters"]
    stub = {n: d for n, _, d in stub_parameters(FUNCTIONS["relax"])}
    for key in ["iterations", "kf", "epsilon", "step_limit", "flux_diffusion"]:
        assert recorded[key] == pytest.approx(stub[key]), key
    # The spectral window is recorded where it applied: photons that carry their wavelength.
    assert "spectral_window" not in recorded
    spectral = photonkit.relax(SAMPLES / "dispersed-beam.phm", iterations=1)
    assert spectral.history[-1]["parameters"]["spectral_window"] == pytest.approx(stub["spectral_window"])
