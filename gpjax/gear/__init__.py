"""Gear-pair physics: the bundled example generator (eqs. 13–14)."""

from ._example import (PAPER_TRUTH, GearExample, Torque, generate_gear_example,
                       load_bundled_example, write_example)

__all__ = ["PAPER_TRUTH", "GearExample", "Torque", "generate_gear_example",
           "load_bundled_example", "write_example"]
