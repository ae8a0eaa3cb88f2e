"""TEST ORACLES: independent readings of the physics, for tests and benches only.

Production code computes the plant in one place, the Rust ``plant`` crate (through
``admittance._rtcore``). Each module here writes some of that physics again, on purpose
differently, so a test can check the plant against something that shares no code with it:

- ``ivp``: Contract 1 with SciPy's ``solve_ivp`` and friction as a switching system
- ``reference``: Contract 1 in plain Python, substep by substep (the Rust plant's scheme)
- ``thesis_ode3``: the thesis's method in plain SciPy (a Python ode3 loop): the bench's baseline
- ``virtual_joint``: one cycle of the RT loop's virtual joint (admittance model and limits)

Nothing under ``admittance/`` imports this package.
"""
