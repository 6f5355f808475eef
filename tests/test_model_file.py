import json

import numpy as np
import pytest

from gpjax import Model, ModelFileError, Symbols
from gpjax.engine import simulate_model
from gpjax.gear import generate_gear_example


def _model():
    return Model(symbols=Symbols("phi", "t", ("T",)), mass=7.918e-5,
                 state={"phi": 413.191, "phi**2": 51721.0}, forcing={"T": 1.0},
                 initial_conditions=(0.010955, -0.6921),
                 metrics={"rms": 1e-5, "f_time": 1e-3, "f_freq": 1e-4, "objective": 1.1e-3})


def test_model_json_round_trip_and_documented_fields(tmp_path):
    model = _model()
    model.save(tmp_path / "model.json")
    data = json.loads((tmp_path / "model.json").read_text())
    for key in ("equation", "latex", "constants", "variables", "initial_conditions", "metrics",
                "canonical"):
        assert key in data
    assert data["equation"] == "Eq(k1*phi + k2*phi**2 + m*phi_ddot, T)"
    assert data["constants"] == {"m": 7.918e-5, "k1": 413.191, "k2": 51721.0}
    assert data["canonical"]["forcing"] == [{"feature": "T", "coefficient": 1.0}]
    again = Model.load(tmp_path / "model.json")
    assert again == model


def test_hand_written_model_with_only_variables_and_canonical_simulates(tmp_path):
    path = tmp_path / "hand.json"
    path.write_text(json.dumps({
        "variables": {"time": "t", "response": "phi", "inputs": ["T"]},
        "canonical": {"mass": 7.918e-5, "terms": [{"feature": "phi", "coefficient": 413.191},
                                                  {"feature": "phi**2", "coefficient": 51721}],
                      "forcing": [{"feature": "T", "coefficient": 1}]}}))
    model = Model.load(path)
    example = generate_gear_example(seed=0, noise_phi=0.0, noise_torque=0.0, revolutions=0.2)
    response, scores = simulate_model(model, example.measurement,
                                      initial_conditions=(0.010955, -0.6921))
    assert np.max(np.abs(response - example.clean_response)) < 2e-3 * np.ptp(example.clean_response)


def test_payload_in_a_feature_does_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "evil.json"
    path.write_text(json.dumps({
        "variables": {"time": "t", "response": "phi", "inputs": ["T"]},
        "canonical": {"mass": 1, "terms": [
            {"feature": "__import__('os').system('touch pwned')", "coefficient": 1}]}}))
    with pytest.raises(ModelFileError, match="not allowed"):
        Model.load(path)
    assert not (tmp_path / "pwned").exists()
