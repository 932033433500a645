"""The members of the estimator family, one module each.

Each holds its settings, its model and its shell subclass, beside its compiled kernel
(``_<member>_core``); ``pilot_filter``, ``pilot_rules`` and ``internal_model`` are what
the members on a pilot model (DEKF, RML, joint and dual UKF) share.
"""
