"""The project's file formats, in one place: the ground floor every other part stands on.

- ``paramfile``: fitted parameter files (Contract 2, ``params/*.toml``), read by the daemon and
  the mock bench, written by ``identify`` and ``fidelity``
- ``dataset``: pendulum datasets (``shared/contracts/datasets.md``): a folder with
  ``manifest.toml`` and one file per trial, validated on load
- ``converters``: foreign recordings (OptiTrack Motive, Dynamixel/BAM logs, DFKI) to datasets
- ``recording``: what ``admittance run --record`` writes (the CSV rows, where a recording is cut
  into trials) and the reader of its ``session.mcap``
- ``mcap_layout``: the topics, schemas and file name of ``session.mcap``

The daemon, identification, fidelity and the mock bench import this package; it imports none
of them (tests/test_import_graph.py holds both rules, and that no module here imports another
that imports it back).
"""
