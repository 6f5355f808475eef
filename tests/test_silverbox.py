"""Silverbox (real measured data, read from ../shared): loader, evidence, full diagnosis."""

import dataclasses

import numpy as np
import pytest

from gpjax import Model, Symbols
from gpjax._data import Measurement
from gpjax._diagnose import (_Problem, diagnose, input_lines, rank_effects, refit,
                              structure_of)
from gpjax._effects import effects
from gpjax._errors import DataError
from gpjax._silverbox import (SAMPLE_RATE, SEGMENTS, load_silverbox, silverbox_segments,
                              segment_rms, upsample)

LINEAR = Model(symbols=Symbols("y", "t", ("u",)), mass=1.0, state={"y": 1.0, "y_dot": 1.0},
               forcing={"u": 1.0})


def test_loader_reads_the_record_and_the_standard_segments(silverbox_dir):
    record = load_silverbox(silverbox_dir)
    assert record.n_samples == 131_072
    assert record.dt == pytest.approx(1 / SAMPLE_RATE, rel=1e-9)
    assert record.input_names == ("u",) and record.response_name == "y"
    segments = silverbox_segments(silverbox_dir)
    for name, (start, stop) in SEGMENTS.items():
        assert segments[name].n_samples == stop - start
        assert np.array_equal(segments[name].response, record.response[start:stop])
    assert 0.0 < np.mean(record.inputs["u"][:80]) < 0.012  # the ~6 mV input offset


def test_upsample_passes_through_the_samples_and_reconstructs_a_band_limited_signal():
    """At 610 Hz a 190 Hz sine interpolated linearly loses half its amplitude between
    samples; the band-limited reconstruction recovers it (away from the record's ends)."""
    fs, n, factor = SAMPLE_RATE, 2000, 4
    time = np.arange(n) / fs

    def signal(t):
        return np.sin(2 * np.pi * 190.0 * t + 0.3) + 0.5 * np.sin(2 * np.pi * 23.0 * t)

    record = Measurement(time=time, response=signal(time), inputs={"u": 2 * signal(time)},
                         time_name="t", response_name="y")
    fine = upsample(record, factor)
    assert fine.n_samples == (n - 1) * factor + 1
    assert fine.dt == pytest.approx(record.dt / factor)
    assert np.array_equal(fine.response[::factor], record.response)
    assert np.array_equal(fine.inputs["u"][::factor], record.inputs["u"])
    inner = slice(100 * factor, -100 * factor)
    exact = signal(fine.time)[inner]
    linear = np.interp(fine.time, time, record.response)[inner]
    assert np.max(np.abs(fine.response[inner] - exact)) < 0.01
    assert np.max(np.abs(linear - exact)) > 0.4
    assert upsample(record, 1) is record
    with pytest.raises(ValueError, match="factor"):
        upsample(record, 0)


def test_loader_refuses_a_folder_without_the_data(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        load_silverbox(tmp_path)


def test_equation_error_evidence_names_the_offset_then_cubic_stiffness(silverbox_dir):
    """The input's ~6 mV DC offset dominates the linear model's equation error; with a
    constant force in the model, cubic stiffness has the most evidence."""
    estimation = silverbox_segments(silverbox_dir)["estimation"]
    problem = _Problem(estimation, LINEAR.symbols, holdout=0.25, iterations=1, substeps=1,
                       batch=1)
    with_offset = dataclasses.replace(LINEAR, forcing={"u": 1.0, "1": 1.0})
    names = []
    for model in (LINEAR, with_offset):
        structure = structure_of(model)
        context = problem.context(structure, tuple(input_lines(problem.train)))
        ranked = rank_effects(problem.weak, structure, context, effects(), problem.u0,
                              polish=False)
        names.append(ranked[0].effect.name)
        assert ranked[0].explained > 0.3
    assert names == ["static_offset", "cubic_stiffness"]


@pytest.mark.slow
@pytest.mark.sweep
def test_diagnosis_adds_cubic_stiffness_first_and_reaches_the_target(silverbox_dir):
    """Full library: cubic stiffness is added first (not the one-sided backlash spring that
    mimics an offset plus a stiffness change) and every test segment improves >= 5x; the
    final structure refitted on the record reconstructed at 4x its rate reaches 0.9 mV
    on 'arrow full'."""
    segments = silverbox_segments(silverbox_dir)
    result = diagnose(segments["estimation"], LINEAR)
    assert result.mode == "simulation"
    assert result.effects_added[0] == "cubic_stiffness", result.effects_added
    models = [fit.model(LINEAR.symbols, {}) for fit in result.fits]
    for name in ("arrow_full", "arrow_no_extrapolation", "multisine"):
        rms = segment_rms(models, segments[name]) * 1e3  # mV
        assert rms[-1] < 0.2 * rms[0], (name, rms)
    factor = 4
    fine = silverbox_segments(silverbox_dir, factor=factor)
    final = refit(fine["estimation"], models[-1:])[0].model(LINEAR.symbols, {})
    assert segment_rms([final], fine["arrow_full"], factor=factor)[0] * 1e3 <= 0.9
