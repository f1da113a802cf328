"""Stereo matchers behind one interface: block matching, semiglobal matching, variational."""

from prismap.stereo._base import (
    StereoMatcher,
    left_right_check,
    left_right_disagreement,
    make_matcher,
    matcher_names,
    search_range,
)

__all__ = [
    "StereoMatcher",
    "left_right_check",
    "left_right_disagreement",
    "make_matcher",
    "matcher_names",
    "search_range",
]
