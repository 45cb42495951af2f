"""``lite-vo profile``: run profiles on sequences, evaluate the runs, report Tables 5.1 / 5.2.

One module per job:

* :mod:`.profiles` - the paper's profiles, ``--profiles`` validation, labels and resolutions
* :mod:`.sweep` - what to run (:class:`~.sweep.RunSpec`), the ``lite-vo run`` command, worker
  processes pinned to cores (:func:`~.sweep.execute`)
* :mod:`.results` - judging one run folder (:func:`~.results.collect_run`) and pooling the runs
  into accuracy and timing tables (:func:`~.results.aggregate`)
* :mod:`.init_study` - the initialisation study of thesis Fig. 5.8 (plan, judge, summarise)
* :mod:`.startup` - the start-up probe, cold vs warm numba cache, the warm-up before a sweep
* :mod:`.machine` - the machine the report was made on
* :mod:`.report` - ``report.md`` and ``report.json``; :mod:`.plots` - PNG plots (matplotlib, lazily)
* :mod:`.command` - :func:`run_profile` and :class:`ProfileSettings`, the entry the CLI uses

The relative drift of the initialisation study is evaluation: :func:`lite_vo.eval.relative_drift`.

``run_profile`` and ``ProfileSettings`` are imported lazily (like ``lite_vo``'s own API) so that
the CLI parser can read :data:`PAPER_PROFILES` without importing numpy.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from .profiles import PAPER_PROFILES, parse_profiles, profile_label, profile_resolution

if TYPE_CHECKING:  # pragma: no cover
    from .command import ProfileSettings, run_profile

_LAZY = {"run_profile": "command", "ProfileSettings": "command"}

__all__ = ["PAPER_PROFILES", "ProfileSettings", "parse_profiles", "profile_label", "profile_resolution",
           "run_profile"]


def __getattr__(name: str):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
