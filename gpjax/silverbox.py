"""The Silverbox benchmark (Wigren & Schoukens, ECC 2013) read from a user's folder.

:func:`load_silverbox` (the whole record), :func:`silverbox_segments` (the estimation and
test segments) and :func:`segment_rms` (a model's simulation error on a test segment by the
reference solve). See :mod:`gpjax._silverbox` for the file format.
"""

from ._silverbox import SEGMENTS, WARMUP, load_silverbox, segment_rms, silverbox_segments

__all__ = ["SEGMENTS", "WARMUP", "load_silverbox", "segment_rms", "silverbox_segments"]
