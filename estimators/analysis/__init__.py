"""Analysis of any member's results: metrics and the frequency domain.

VAF, NRMSE and the other metrics, the describing function at the forcing frequencies,
the fit cross-checks, human-likeness, and the identification of one recording.
"""
