"""The completer base class: a runtime that implements only ``_forward`` gets the input checks, the box handling,
batching, the default-clip placeholder and the clamping into the grown box and the unit sphere."""

from __future__ import annotations

import numpy as np
import pytest

from spotlights.errors import ParameterError
from spotlights.geometry.rig import make_rig_spec
from spotlights.learning.domain import LearnedDomain
from spotlights.learning.export import OnnxCompleter
from spotlights.learning.inference import DEFAULT, BaseCompleter, Completer


class Scaled(BaseCompleter):
    """A fake network: every input point times 3 (so outside the unit sphere); records its calls."""

    model_name, n_params, clip, threshold, domain = "scaled", 0, None, None, LearnedDomain()

    def __init__(self, needs_box: bool):
        self.needs_box = needs_box
        self.rig = make_rig_spec(4, 8, kind="box") if needs_box else None
        self.calls: list = []

    def _forward(self, partials, clip, directions, sensor_origins=None):
        self.calls.append((partials.shape, partials.dtype, clip, None if directions is None else directions.shape))
        return [3.0 * p for p in partials]


def test_only_the_forward_pass_is_the_runtimes():
    """Both runtimes are completers of the base class and inherit its public methods unchanged."""
    for runtime in (Completer, OnnxCompleter):
        assert issubclass(runtime, BaseCompleter)
        for name in ("complete", "complete_boxes"):
            assert name not in vars(runtime) and getattr(runtime, name) is getattr(BaseCompleter, name)


def test_checks_batches_and_placeholder():
    c = Scaled(needs_box=False)
    x = np.random.default_rng(0).uniform(-0.3, 0.3, (5, 7, 3))
    out = c.complete(x, batch_size=2)
    assert [s for s, *_ in c.calls] == [(2, 7, 3), (2, 7, 3), (1, 7, 3)]
    assert all(dt == np.float32 and clip is DEFAULT and d is None for _, dt, clip, d in c.calls)
    np.testing.assert_allclose(np.stack(out), 3.0 * x.astype(np.float32), rtol=1e-6)
    assert len(c.complete(x[0])) == 1 and c.complete(np.zeros((0, 7, 3))) == []
    for bad, msg in (
        (np.zeros((2, 7)), r"\(B, K, 3\)"),
        (np.zeros((2, 0, 3)), "empty"),
        (np.full((1, 4, 3), np.nan), "NaN"),
    ):
        with pytest.raises(ParameterError, match=msg):
            c.complete(bad)


def test_box_rigs_get_each_scans_directions_and_results_are_clamped():
    c = Scaled(needs_box=True)
    x = np.random.default_rng(1).uniform(-0.6, 0.6, (3, 16, 3))
    with pytest.raises(ParameterError, match="half-extents"):
        c.complete(x)
    with pytest.raises(ParameterError, match=r"\(3, 3\) or \(3,\)"):
        c.complete(x, extents=np.ones((2, 3)) / np.sqrt(3))
    sizes = np.array([[4.0, 2.0, 1.5], [4.5, 1.8, 1.6], [3.0, 3.0, 3.0]])
    out = c.complete_boxes(x, sizes, clip=0.1)
    assert c.calls[-1][2:] == (0.1, (3, 32, 3))  # 4 viewpoints x 8 rays, one set per scan
    for p, q, size in zip(out, x, sizes):
        # by hand: each coordinate clipped to the box grown by 0.15 m (unit frame: metres / R, R = half the
        # diagonal), then points outside the unit sphere moved radially onto it
        radius = np.linalg.norm(size) / 2
        half = (size / 2 + 0.15) / radius
        inbox = np.clip(q * 3.0, -half, half)
        r = np.linalg.norm(inbox, axis=1, keepdims=True)
        expect = inbox / np.maximum(r, 1.0)
        np.testing.assert_allclose(p.astype(np.float64), expect, rtol=1e-5, atol=1e-6)
        assert np.linalg.norm(p.astype(np.float64), axis=1).max() <= 1.0 + 1e-6


def test_a_request_object_is_the_same_call_as_its_keywords():
    """``complete(CompletionRequest(x, ...))`` gives what ``complete(x, ...)`` gives; options beside a request are
    refused (one way to say each option)."""
    from spotlights.learning.inference import CompletionRequest

    c = Scaled(needs_box=True)
    x = np.random.default_rng(0).uniform(-0.5, 0.5, (3, 7, 3)).astype(np.float32)
    e = np.array([0.8, 0.4, 0.3])
    by_words = c.complete(x, batch_size=2, extents=e)
    by_request = c.complete(CompletionRequest(x, batch_size=2, extents=e))
    assert [s for s, *_ in c.calls] == [(2, 7, 3), (1, 7, 3)] * 2
    assert len(by_words) == len(by_request) == 3
    for a, b in zip(by_words, by_request):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ParameterError, match="in the request"):
        c.complete(CompletionRequest(x), batch_size=2)
    with pytest.raises(ParameterError, match="3 class names for 2 scans"):
        c.complete(CompletionRequest(x[:2], extents=e, classes=["a", "b", "c"]))
