"""The record as the programs' argument (gpjax._record): lengths padded to buckets, the
padding masked out exactly, and a program compiled for one record serving another record
of its bucket with that record's own results."""

import dataclasses

import numpy as np
import pytest
import sympy as sp

from gpjax import Measurement, Symbols
from gpjax._coefficients import Coefficients, to_population
from gpjax._evaluator import PopulationEvaluator
from gpjax._objective import DFT_MATRIX_LIMIT
from gpjax._record import BUCKETS_PER_OCTAVE, band_floor, padded_bins, padded_length
from gpjax._refine import Refiner

S = Symbols("x", "t", ("u",))
X, V, U = sp.symbols("x x_dot u")


def test_buckets_hold_every_length_with_at_most_a_quarter_more():
    lengths = np.arange(1, 70_000)
    padded = np.array([padded_length(n) for n in lengths])
    assert np.all(padded >= lengths) and np.all(padded[15:] <= 1.25 * lengths[15:])
    assert len(set(padded[(lengths > 4096) & (lengths <= 8192)])) == BUCKETS_PER_OCTAVE
    assert padded_length(1024) == 1024 and padded_length(1025) == 1280


def test_records_of_one_length_whose_bins_differ_within_an_octave_share_the_programs():
    """The bins follow a record's band: 136 and 203 (issue 43's pendulum and Duffing) lie
    in one bucket, so their evaluators have one program key."""
    assert padded_bins(136) == padded_bins(203) == 256 and padded_bins(257) == 512
    record = _record(0, 2000)
    keys = {PopulationEvaluator(record, S, max_degree=3, n_bins=bins).key for bins in (136, 203)}
    assert len(keys) == 1


def test_records_whose_bins_straddle_a_power_of_two_share_the_programs_above_the_band_floor():
    """2,001-sample records of one system held 26–40 bins (32 or 64 by the octave alone):
    the floor of f_s/32 holds 64 for all, so one key; the floor stops at the DFT-matrix
    limit."""
    assert band_floor(2048) == 64 and padded_bins(26, 2048) == padded_bins(40, 2048) == 64
    assert 2 * band_floor(1 << 15) * (1 << 15) <= DFT_MATRIX_LIMIT
    record = _record(0, 2001)
    keys = {PopulationEvaluator(record, S, max_degree=3, n_bins=bins).key for bins in (26, 40)}
    assert len(keys) == 1


def _record(seed: int, n: int) -> Measurement:
    """A Duffing oscillator under a random multisine, 100 Hz, 0.1 % noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    u = sum(a * np.sin(2 * np.pi * f * t + p) for a, f, p in
            zip(rng.uniform(2, 6, 5), rng.uniform(0.2, 3.0, 5), rng.uniform(0, 6, 5)))
    x, v, position = np.zeros(n), 0.0, 0.0
    for k in range(1, n):  # semi-implicit Euler, 20 steps a sample
        for _ in range(20):
            v += 0.0005 * (u[k - 1] - 0.4 * v - 30.0 * position - 200.0 * position ** 3)
            position += 0.0005 * v
        x[k] = position
    x += 1e-3 * np.std(x) * rng.standard_normal(n)
    return Measurement(time=t, response=x, inputs={"u": u}, response_name="x")


def _models(evaluator):
    equations = [Coefficients(1.0, {X: 30.0, X ** 3: 200.0, V: 0.4}, {U: 1.0}, (0.0, 0.0)),
                 Coefficients(1.1, {X: 25.0, V: 0.5}, {U: 1.0}, (0.001, 0.0)),
                 Coefficients(0.9, {X: 35.0, X ** 3: 150.0, V: 0.3}, {U: 0.9}, (0.0, 0.01))]
    return to_population(equations, evaluator)


def _pair(measurement, **settings):
    padded = PopulationEvaluator(measurement, S, max_degree=3, batch=4, **settings)
    exact = PopulationEvaluator(measurement, S, max_degree=3, batch=4, pad_to_bucket=False,
                                **settings)
    return padded, exact


@pytest.mark.parametrize("fit_initial_conditions", [False, True])
def test_the_padding_changes_no_score(fit_initial_conditions):
    """A 1,100-sample record padded to 1,280 scores and simulates as unpadded."""
    padded, exact = _pair(_record(0, 1100), fit_initial_conditions=fit_initial_conditions)
    assert (padded.n_padded, exact.n_padded) == (1280, 1100)
    responses, scores = padded.simulate(_models(padded))
    reference, reference_scores = exact.simulate(_models(exact))
    assert responses.shape == reference.shape == (3, 1100)
    np.testing.assert_allclose(responses, reference, rtol=1e-12, atol=1e-15)
    for name in ("objective", "f_time", "f_freq", "rms", "y0"):
        np.testing.assert_allclose(getattr(scores, name), getattr(reference_scores, name),
                                   rtol=1e-10, atol=1e-15)
    assert np.all(scores.status == reference_scores.status)


@pytest.mark.slow  # 13-21 s: the fast tier stays within 5 minutes on 2 cores
def test_the_padding_changes_no_refined_constant():
    """Levenberg–Marquardt on the padded record reaches the unpadded record's constants,
    through the same continuation (each horizon fits the same samples of the record)."""
    padded, exact = _pair(_record(1, 1100), fit_initial_conditions=True)
    out = []
    for evaluator in (padded, exact):
        refiner = Refiner(evaluator, iterations=20, batch=4)
        start = _models(evaluator)
        out.append(refiner.refine(start, np.full(3, evaluator.forcing_index(U))))
    np.testing.assert_allclose(out[0].population.state, out[1].population.state, rtol=1e-7)
    np.testing.assert_allclose(out[0].population.mass, out[1].population.mass, rtol=1e-7)
    assert np.array_equal(out[0].succeeded, out[1].succeeded)


def test_a_program_of_another_record_of_the_bucket_gives_this_records_results(
        tmp_path, monkeypatch):
    """Record B (another input, length and noise) loads the executable compiled for record
    A from the cache folder, and scores as B compiled on its own."""
    monkeypatch.setenv("GPJAX_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("GPJAX_COMPILATION_CACHE", "on")
    first = PopulationEvaluator(_record(2, 1200), S, max_degree=3, batch=4)
    first.score(_models(first))
    stored = sorted((tmp_path / "programs").iterdir())
    second = PopulationEvaluator(_record(3, 1111), S, max_degree=3, batch=4)
    assert second.key == first.key
    scores = second.score(_models(second))
    assert sorted((tmp_path / "programs").iterdir()) == stored  # loaded, nothing new
    monkeypatch.setenv("GPJAX_COMPILATION_CACHE", "off")
    alone = PopulationEvaluator(_record(3, 1111), S, max_degree=3, batch=4,
                                pad_to_bucket=False)
    reference = alone.score(_models(alone))
    for field in dataclasses.fields(scores):
        np.testing.assert_allclose(getattr(scores, field.name),
                                   getattr(reference, field.name), rtol=1e-10, atol=1e-15)
