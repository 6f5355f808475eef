"""Silverbox (real measured data, read from ../shared): loader, evidence, full diagnosis."""

import dataclasses

import numpy as np
import pytest

from gpjax import Model, Symbols
from gpjax._diagnose import _Problem, diagnose, input_lines, rank_effects, structure_of
from gpjax._effects import effects
from gpjax._errors import DataError
from gpjax._silverbox import (SAMPLE_RATE, SEGMENTS, load_silverbox, silverbox_segments,
                              segment_rms)

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
def test_diagnosis_improves_every_test_segment_and_finds_cubic_stiffness(silverbox_dir):
    """Full library: every test segment improves >= 5x and cubic stiffness is added. Without
    backlash (a one-sided dead-zone spring that can mimic a hardening spring plus an offset)
    cubic stiffness is the first effect added."""
    segments = silverbox_segments(silverbox_dir)
    for library, first in ((effects(), None), ({k: v for k, v in effects().items()
                                                if k != "backlash"}, "cubic_stiffness")):
        result = diagnose(segments["estimation"], LINEAR, library=library)
        assert result.mode == "simulation"
        assert "cubic_stiffness" in result.effects_added
        if first:
            assert result.effects_added[0] == first
        models = [fit.model(LINEAR.symbols, {}) for fit in result.fits]
        for name in ("arrow_full", "arrow_no_extrapolation", "multisine"):
            rms = segment_rms(models, segments[name]) * 1e3  # mV
            assert rms[-1] < 0.2 * rms[0], (name, rms)
        assert segment_rms(models[-1:], segments["arrow_full"])[0] * 1e3 <= 1.0
