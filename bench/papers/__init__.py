"""Paper-specific report sections, one module per built-in suite.

A suite named ``schiess-roland1975`` may have a module ``schiess_roland1975`` here with a
function ``report_section(suite, rows, out) -> list[str]`` that returns Markdown lines
(tables beside the paper's, extra figures written under ``out/figures``);
:func:`manualcontrol.bench.report.write_report` appends them after the batch tables.
Suites without such a module get the generic report only.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from typing import Any

__all__ = ["section_writer"]


def section_writer(suite_name: str) -> Callable[..., Sequence[str]] | None:
    """The ``report_section`` function for ``suite_name``, or None when there is none."""
    module_name = suite_name.replace("-", "_")
    if not module_name.isidentifier():
        return None
    try:
        module: Any = importlib.import_module(f"{__name__}.{module_name}")
    except ModuleNotFoundError as error:
        if error.name == f"{__name__}.{module_name}":
            return None
        raise
    return getattr(module, "report_section", None)
