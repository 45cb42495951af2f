"""Slow, obviously-correct numpy versions of every numba kernel, one module per package.

Tests compare each kernel against its twin here; the twins live in ``naive_<package>.py``.
"""
from naive_ar import *  # noqa: F401,F403
from naive_mapping import *  # noqa: F401,F403
from naive_synth import *  # noqa: F401,F403
from naive_tracking import *  # noqa: F401,F403
