"""Gear-pair physics: the bundled example (eqs. 13–14), mesh stiffness (eqs. 15–20), the
2-DOF gear-pair model (eqs. 21–23) and a measured record of it with known truth, the
linear eq. 23 fit (the paper's Fig. 12) and gear
data with an effect the model does not declare (the diagnosis checks)."""

from ._example import (PAPER_TRUTH, GearExample, Torque, generate_gear_example,
                       load_bundled_example, write_example)
from ._linear import LinearFit, fit_linear_model
from ._stiffness import (KUANG_YANG_COEFFICIENTS, ContactPoints, GearPair, MeshGeometry,
                         MeshStiffness, average_mesh_stiffness, bending_stiffness,
                         contact_points, hertz_stiffness, iso6336_stiffness,
                         kuang_yang_coefficients, mesh_cycle_angles, mesh_stiffness,
                         pair_stiffness, stiffness_report, torsional_stiffness)
from ._undeclared import (EFFECTS, NEAREST, NOISE_LEVELS, NOISE_PHI, NOISE_TORQUE, OUTSIDE,
                          REPORTING_SEEDS, TUNING_SEEDS, UndeclaredEffectCase,
                          undeclared_effect_case)
from ._two_dof import (OneDofResponse, TwoDofGearPair, TwoDofResponse, mesh_stiffness_signal,
                       reduction_error, reduction_scenarios, simulate_one_dof,
                       simulate_two_dof)
from ._two_dof_record import TwoDofRecord, two_dof_record

__all__ = [
    "PAPER_TRUTH", "GearExample", "Torque", "generate_gear_example", "load_bundled_example",
    "write_example", "LinearFit", "fit_linear_model", "KUANG_YANG_COEFFICIENTS", "ContactPoints", "GearPair", "MeshGeometry",
    "MeshStiffness", "average_mesh_stiffness", "bending_stiffness", "contact_points",
    "hertz_stiffness", "iso6336_stiffness", "kuang_yang_coefficients", "mesh_cycle_angles",
    "mesh_stiffness", "pair_stiffness", "stiffness_report", "torsional_stiffness",
    "OneDofResponse", "TwoDofGearPair", "TwoDofResponse", "mesh_stiffness_signal",
    "reduction_error", "reduction_scenarios", "simulate_one_dof", "simulate_two_dof",
    "TwoDofRecord", "two_dof_record",
    "EFFECTS", "NEAREST", "NOISE_LEVELS", "NOISE_PHI", "NOISE_TORQUE", "OUTSIDE",
    "REPORTING_SEEDS", "TUNING_SEEDS", "UndeclaredEffectCase", "undeclared_effect_case",
]
