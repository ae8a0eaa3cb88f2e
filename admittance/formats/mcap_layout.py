"""The layout of ``session.mcap`` (``admittance run --record``): its name, its channels' JSON
schemas, and the columns of a cycle message. The table of channels is in
``admittance.daemon.mcap_recording`` (the writer) and docs/foxglove.md; the reader is
``admittance.formats.recording.read_recording``.
"""

from __future__ import annotations

MCAP_NAME = "session.mcap"  # inside a --record folder
MCAP_CYCLE_COLUMNS = ("t", "t_wake", "wall", "cycle", "force", "tau", "theta_model", "omega_model", "theta_goal",
                      "theta_present", "rendering_error", "fault", "mode")
NUMBER = {"type": "number"}
NULLABLE = {"type": ["number", "null"]}
CYCLE_SCHEMA = {
    "title": "admittance.Cycle", "type": "object",
    "properties": {"t": NUMBER, "t_wake": NUMBER, "wall": NUMBER, "cycle": {"type": "integer"}, "force": NUMBER,
                   "tau": NUMBER, "theta_model": NUMBER, "omega_model": NUMBER, "theta_goal": NUMBER,
                   "theta_present": NULLABLE, "rendering_error": NULLABLE, "fault": {"type": "integer"},
                   "mode": {"type": "integer"}, "passivity_energy": NUMBER, "passivity_damping": NUMBER},
}
OBJECT = {"type": "object"}
SESSION_SCHEMA = {"title": "admittance.Session", "type": "object",
                  "properties": {"joints": {"type": "array"}, "t0": NUMBER, "segment_s": NUMBER,
                                 "measured_theta": {"type": "boolean"}, "rate_hz": NUMBER, "prefix": {"type": "string"}}}
PARAMS_SCHEMA = {"title": "admittance.Params", "type": "object",
                 "properties": {"source": {"type": "string"}, "request": OBJECT, "params": OBJECT}}
EVENT_SCHEMA = {"title": "admittance.Event", "type": "object", "properties": {"text": {"type": "string"}}}
