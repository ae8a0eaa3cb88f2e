"""Bring-up of a new bench: from a box of parts to a first admittance session (``admittance setup``).

One module per step, each usable on its own and each run by :mod:`wizard`:

- ``scan``    find the servos: IDs, models, protocols and baud rates;
- ``servo``   change a servo's ID, baud rate or operating mode safely (torque off, verified);
- ``arm``     the hanging rest (``zero_tick``) and the positive direction, from a push;
- ``sensor``  the force axis, its sign and the lever arm, from a push against a holding servo;
- ``dryrun``  a short admittance session with the servo's output limited;
- ``wizard``  the steps in order, interactive or scripted, writing a validated configuration.

The method behind each measurement is in docs/bring-up.md.
"""
