"""Slow, obviously-correct numpy versions of every numba kernel, one module per package.

Tests compare each kernel against its twin in ``naive_<package>.py``; this module gives them one
name space each (``naive.mapping.gradients`` and ``naive.tracking.gradients`` differ).
"""
import naive_ar as ar  # noqa: F401
import naive_mapping as mapping  # noqa: F401
import naive_synth as synth  # noqa: F401
import naive_tracking as tracking  # noqa: F401
