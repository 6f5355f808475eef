import json

import numpy as np
import pytest

from gpjax import Model, ModelFileError, Symbols
from gpjax.engine import simulate_model
from gpjax.gear import generate_gear_example


def _model():
    return Model.single(symbols=Symbols("phi", "t", ("T",)), mass=7.918e-5,
                 state={"phi": 413.191, "phi**2": 51721.0}, forcing={"T": 1.0},
                 initial_conditions=(0.010955, -0.6921),
                 metrics={"rms": 1e-5, "f_time": 1e-3, "f_freq": 1e-4, "objective": 1.1e-3})


def test_model_json_round_trip_and_documented_fields(tmp_path):
    model = _model()
    model.save(tmp_path / "model.json")
    data = json.loads((tmp_path / "model.json").read_text())
    for key in ("equations", "latex", "constants", "variables", "initial_conditions", "metrics",
                "canonical"):
        assert key in data
    assert (data["format"], data["version"]) == ("gpjax-model", 2)
    assert data["equations"] == ["Eq(k1*phi + k2*phi**2 + m*phi_ddot, T)"]
    assert data["variables"]["responses"] == ["phi"]
    assert data["constants"] == {"m": 7.918e-5, "k1": 413.191, "k2": 51721.0}
    assert data["canonical"][0]["forcing"] == [{"feature": "T", "coefficient": 1.0}]
    assert data["initial_conditions"] == [{"response": 0.010955, "response_dot": -0.6921}]
    again = Model.load(tmp_path / "model.json")
    assert again == model


def test_a_version_1_file_reads_as_the_same_model(tmp_path):
    """Version 1 (one coordinate: ``variables.response``, one ``canonical`` object, one
    initial-conditions object) is the same model as its version-2 rewrite."""
    model = _model()
    data = model.to_json()
    data |= {"version": 1, "equation": data.pop("equations")[0],
             "variables": {"time": "t", "response": "phi", "inputs": ["T"]},
             "canonical": data["canonical"][0],
             "initial_conditions": data["initial_conditions"][0]}
    (tmp_path / "v1.json").write_text(json.dumps(data))
    assert Model.load(tmp_path / "v1.json") == model


def _chain(**fields):
    return Model.from_json({
        "variables": {"time": "t", "responses": ["x1", "x2"], "inputs": ["u"]},
        "canonical": [
            {"mass": 1.0, "terms": [{"feature": "x1_dot", "coefficient": 0.5},
                                    {"feature": "x1 - x2", "coefficient": 40.0}],
             "forcing": [{"feature": "u", "coefficient": 1.0}]},
            {"mass": 2.0, "terms": [{"feature": "x2 - x1", "coefficient": 40.0},
                                    {"feature": "(x2 - x1)**3", "coefficient": 3.0}],
             "forcing": []}],
        "initial_conditions": [{"response": 0.0, "response_dot": 0.0}] * 2, **fields})


def test_a_model_of_two_coordinates_round_trips_and_names_its_constants(tmp_path):
    model = _chain()
    assert model.n_coordinates == 2 and model.coordinates == ("x1", "x2")
    assert model.constants() == {"x1.m": 1.0, "x1.k1": 40.0, "x1.c1": 0.5, "x2.m": 2.0,
                                 "x2.k1": 40.0, "x2.k2": 3.0}
    assert str(model.equation(1)) == "Eq(x2.k1*(-x1 + x2) + x2.k2*(-x1 + x2)**3 + x2.m*x2_ddot, 0)"
    assert len(model.sympy()) == 2 and len(model.latex()) == 2
    model.save(tmp_path / "chain.json")
    assert Model.load(tmp_path / "chain.json") == model
    from gpjax import Equation  # the same model built in Python
    assert Model(coordinates=("x1", "x2"), time="t", inputs=("u",), equations=(
        Equation(1.0, {"x1_dot": 0.5, "x1 - x2": 40.0}, {"u": 1.0}),
        Equation(2.0, {"x2 - x1": 40.0, "(x2 - x1)**3": 3.0}, {})),
        initial_states=((0.0, 0.0), (0.0, 0.0))) == model
    with pytest.raises(ValueError, match="2 .x1, x2.: use model.equations"):
        model.mass


def test_a_gpjax_system_file_reads_as_a_model(tmp_path):
    model = _chain()
    data = model.to_json()
    system = {"format": "gpjax-system", "version": 1, "third_law": False,
              "variables": data["variables"], "system": data.pop("canonical"),
              "initial_conditions": data["initial_conditions"],
              "simulation": {"input_interpolation": "linear", "max_degree": 3,
                             "integrator": {"method": "rk4", "substeps": 1}}}
    (tmp_path / "system.json").write_text(json.dumps(system))
    assert Model.load(tmp_path / "system.json") == model


@pytest.mark.parametrize("change, message", [
    ({"version": 3}, "version 3 is not one this gpjax reads"),
    ({"format": "other"}, "format 'other'"),
])
def test_an_unknown_format_or_version_is_refused(change, message):
    with pytest.raises(ModelFileError, match=message):
        _chain(**change)


@pytest.mark.parametrize("equation, feature, message", [
    (0, "x1*x2", "must depend on x1 alone or on x1_dot alone or of x_i - x_j"),
    (1, "x2_dot*x1", "must depend on x2 alone"),
    (1, "sin(2*x2)", "neither a power nor a bank term"),
    (0, "x1*u", "must depend on x1 alone"),
])
def test_every_equation_of_several_is_checked(equation, feature, message):
    data = _chain().to_json()
    data["canonical"][equation]["terms"].append({"feature": feature, "coefficient": 1.0})
    with pytest.raises(ModelFileError, match=message):
        Model.from_json(data)


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
