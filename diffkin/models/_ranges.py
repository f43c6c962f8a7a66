"""The old name of :mod:`diffkin.models.ranges`, kept while ``diffkin/workspace/`` still imports it (issue 55)."""

from diffkin.models.ranges import ball_starts, into_cones, sampling_ranges, uniform

__all__ = ["ball_starts", "into_cones", "sampling_ranges", "uniform"]
