"""Property tests (hypothesis) over ``tuner.identify``'s inputs and export names (issue 21), like those over
``tune`` in tests/tuner/test_properties.py: every input either returns or raises TunerError naming a field,
never anything else (no numpy error, no RuntimeWarning: pytest's config makes one an error)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from tuner.errors import TunerError
from tuner.export.codegen import check_name
from tuner.identify import identify

SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
                derandomize=True)
FIELDS = {"input", "output", "time", "rate_hz", "band", "holdout", "poles", "zeros", "delay", "delay_step",
          "coherence_min", "n_points", "n_starts", "seed"}


def _chirp(n: int, rate: float) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) / rate
    u = np.sin(2 * np.pi * (0.2 + 2.0 * t / t[-1]) * t)
    y = np.zeros(n)
    a = np.exp(-5.0 / rate)
    for k in range(1, n):  # a first-order lag, exactly sampled
        y[k] = a * y[k - 1] + (1 - a) * u[k - 1]
    return u, y


special = st.sampled_from([np.nan, np.inf, -np.inf, 0.0, 1e-300, 1e300, -1e300])


@st.composite
def records(draw):
    n = draw(st.sampled_from([0, 1, 5, 127, 128, 400, 1200, 1200, 1200]))
    rate = draw(st.sampled_from([50.0, 1.0, 1e-3, 1e6]))
    u, y = _chirp(max(n, 2), rate)
    u, y = u[:n], y[:n]
    scale = draw(st.sampled_from([1.0, 1e-13, 1e-300, 1e59, 1e200]))
    u, y = u * scale, y * draw(st.sampled_from([1.0, scale]))
    kind = draw(st.sampled_from(["plain"] * 4 + ["poison", "constant", "shape", "list", "short_output", "same"]))
    if kind == "poison" and n:
        u = u.copy()
        u[draw(st.integers(0, n - 1))] = draw(special)
    elif kind == "constant":
        u = np.full(n, draw(st.sampled_from([0.0, 1.0, 1e-200])))
    elif kind == "shape":
        u = u.reshape(1, -1) if draw(st.booleans()) else np.stack([u, u], axis=-1)
    elif kind == "list":
        u = [[1.0, 2.0], [3.0]] if draw(st.booleans()) else "abc"
    elif kind == "short_output":
        y = y[: max(0, n - 3)]
    elif kind == "same":
        y = u
    return u, y, rate


options = st.fixed_dictionaries({}, optional={  # valid values more often than not, and every kind of invalid one
    "poles": st.sampled_from([1, 1, 2, 2, 0, 9, 1.5]),
    "zeros": st.sampled_from([0, 0, 0, 1, 3]),
    "delay": st.sampled_from(["auto", "auto", None, 0.0, 0.02, 1e9, -1.0, float("nan"), "soon"]),
    "holdout": st.sampled_from([0.2, 0.2, 0.0, 0.5, 0.9, -0.1]),
    "band": st.sampled_from([None, None, (0.5, 20.0), (20.0, 0.5), (1e-9, 1e9), (1.0,)]),
})


@given(rec=records(), opts=options)
@settings(max_examples=100, **SETTINGS)
def test_identify_returns_or_raises_tuner_error_naming_a_field(rec, opts):
    u, y, rate = rec
    opts = {"poles": 1, "n_starts": 2, **opts}
    try:
        res = identify(u, y, rate_hz=rate, **opts)
    except TunerError as e:
        event(f"refused: {e.field[:1]}")
        assert str(e)
        if e.field:  # an identification error (the fit failed) may concern no single input
            assert str(e.field[0]) in FIELDS, e.field
        return
    event("identified")
    assert np.isfinite(res.cost) and res.quality in ("good", "acceptable", "poor")
    assert np.all(np.isfinite(res.model.theta))


@given(n=st.sampled_from([400, 1200]), rate=st.sampled_from([50.0, 1.0, 1e-3, 1e6]),
       su=st.sampled_from([1e-13, 1e-3, 1.0, 1e4, 1e59]), sy=st.sampled_from([1e-13, 1.0, 1e59]),
       delay=st.sampled_from(["auto", None]), holdout=st.sampled_from([0.0, 0.2]))
@settings(max_examples=40, **SETTINGS)
@pytest.mark.slow  # (over ~2 s: the fast lane stays under 3 min)
def test_a_well_excited_record_in_any_units_and_at_any_rate_is_identified(n, rate, su, sy, delay, holdout):
    """The same first-order lag, exactly sampled, in any units of input and output (1e-13 ... 1e59) and at any
    sample rate: a finite model, whose gain carries the units (sy / su) and whose pole does not."""
    u, y = _chirp(n, rate)
    ref = identify(u, y, rate_hz=rate, poles=1, delay=delay, holdout=holdout, n_starts=2)
    res = identify(u * su, y * sy, rate_hz=rate, poles=1, delay=delay, holdout=holdout, n_starts=2)
    assert np.all(np.isfinite(res.model.theta))
    assert res.model.gain == pytest.approx(ref.model.gain * sy / su, rel=1e-6)
    np.testing.assert_allclose(res.model.theta[1:], ref.model.theta[1:], rtol=1e-6, atol=1e-9)


@given(name=st.text(max_size=40))
@settings(max_examples=300, **SETTINGS)
def test_check_name_accepts_only_portable_c_identifiers(name):
    try:
        assert check_name(name) == name
    except TunerError as e:
        assert e.field == ("name",)
        return
    # accepted: ASCII letter first, then letters, digits, _ (no leading _: reserved in C at file scope)
    assert name[:1].isascii() and name[:1].isalpha()
    assert all(c.isascii() and (c.isalnum() or c == "_") for c in name)


@pytest.mark.parametrize("name", ["_", "_x", "__x", "_X", "int", "class", "9a", "a-b", "é", ""])
def test_check_name_refuses(name):
    with pytest.raises(TunerError) as e:
        check_name(name)
    assert e.value.field == ("name",)
