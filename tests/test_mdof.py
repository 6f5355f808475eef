"""Several degrees of freedom: measurements with several responses and the coupled,
batched simulation of systems (issue 14)."""

from __future__ import annotations

import numpy as np
import pytest

import gpjax
from gpjax import DataError
from gpjax.systems import generate, write_csv


def _two(n=200):
    t = np.arange(n) * 0.01
    return t, np.stack([np.sin(5 * t), np.cos(3 * t)], axis=1), {"u": np.cos(t)}


def test_measurement_holds_several_responses_and_keeps_the_one_response_view():
    t, responses, inputs = _two()
    one = gpjax.Measurement(time=t, response=responses[:, 0], inputs=inputs)
    assert one.n_coordinates == 1 and one.responses.shape == (200, 1)
    np.testing.assert_array_equal(one.response, responses[:, 0])
    two = gpjax.Measurement(time=t, responses=responses, response_names=("a", "b"),
                            inputs=inputs)
    assert two.n_coordinates == 2 and two.response_names == ("a", "b")
    np.testing.assert_array_equal(two.segment(10, 50).responses, responses[10:50])
    assert two.fingerprint() != one.fingerprint()
    with pytest.raises(DataError, match="supports one response, got 2"):
        two.response


@pytest.mark.parametrize("names, inputs, message", [
    (("a", "a"), {"u": None}, "response 'a' is named twice"),
    (("a", "u"), {"u": None}, "'u' is named twice, as a response and as an input"),
])
def test_bad_response_names_are_refused(names, inputs, message):
    t, responses, _ = _two()
    with pytest.raises(DataError, match=message):
        gpjax.Measurement(time=t, responses=responses, response_names=names,
                          inputs={k: np.cos(t) for k in inputs})


def test_load_csv_reads_several_responses(tmp_path):
    data = generate("chain2", seed=0)
    write_csv(data.fit, tmp_path / "chain.csv")
    measurement = gpjax.load_csv(tmp_path / "chain.csv", time="t", responses=["x2", "x1"],
                                 inputs=["u"])
    assert measurement.response_names == ("x2", "x1")
    np.testing.assert_allclose(measurement.responses, data.fit.response_measured[::-1].T,
                               rtol=1e-15)
    with pytest.raises(DataError, match="'x1' is named twice"):
        gpjax.load_csv(tmp_path / "chain.csv", time="t", responses=["x1", "x1"])


def test_columns_of_different_lengths_are_refused(tmp_path):
    rows = ["t,x1,x2"] + [f"{i * 0.01},{np.sin(i / 5)},{np.cos(i / 7) if i < 40 else 'nan'}"
                          for i in range(60)]
    (tmp_path / "r.csv").write_text("\n".join(rows) + "\n")
    with pytest.raises(DataError, match="'x2' of .* has 40 samples but 't' has 60"):
        gpjax.load_csv(tmp_path / "r.csv", time="t", responses=["x1", "x2"])
