"""Rendering fidelity: what the joint really renders, and the servo model that closes the gap.

``admittance fidelity RECORDING`` (../shared/contracts/fidelity.md, docs/fidelity.md) reads a
recording of ``admittance run --record`` and measures the gap between the admittance model and
the horn: the rendering error (present − model angle), the admittance the horn really rendered
(``identify`` on the measured angle) against the one the loop ran, and the servo's tracking
dynamics (goal and hand torque → present angle, ``plant::servo``), which a parameter file can
carry so that the RT loop compensates for it.

- ``recording``: read and check a recording (columns, joints, what the loop ran).
- ``servo``: fit the servo model to a recording, score it on held-out segments, judge its residual.
- ``report``: the JSON of the contract and the parameter file with the servo model.
- ``cli``: the ``fidelity`` subcommand.
"""
