"""HORA: teacher and student declarations (``teacher``, ``student``), what both stages share (``common``)
and their JAX learners."""
