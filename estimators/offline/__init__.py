"""Offline methods on any member's results: they use the whole run.

Fixed-interval smoothing, the smoothed and cross-validated twins, the schedule
(sigmoid) fit and the output-error fit.
"""
