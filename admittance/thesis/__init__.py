"""The thesis's own procedures (Rao, NJIT 2016), reproduced: ``admittance thesis``, ``breakaway``
and ``predict``.

- ``alternating``: the per-trial alternating (I, B) / F fit, in the thesis's table layout
  (tables 3.2–3.4), on the Rust plant
- ``breakaway``: breakaway friction from slow torque ramps (table 3.1)
- ``predict``: section 3.3's testing trials: torque → position through the plant's simulator,
  position → torque through the plant's inverse (``_rtcore.required_torque``)

These are procedures of the thesis, kept to reproduce its numbers (docs/thesis-reproduction.md);
the identification pipeline (``admittance.ident``) is what the project uses to fit a plant. The
thesis method written again in plain SciPy (the benchmark's baseline) is a test oracle:
``tests/oracles/thesis_ode3.py``.
"""
