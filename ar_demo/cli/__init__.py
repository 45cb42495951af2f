"""The AR demo's ``lite-vo`` commands (``ar``, ``demo``), registered with the core through the
entry-point group ``lite_vo.commands`` (see pyproject.toml). Argparse only at module level: the
commands import pybullet, moderngl and trimesh when they run, and say how to install them when
they are missing."""
