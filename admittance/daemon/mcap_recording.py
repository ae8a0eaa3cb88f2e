"""``DIR/session.mcap``: every cycle of a ``--record`` session, for Foxglove and for ``identify``.

Beside the CSV dataset (the contract's format, rows only where the servo was read), the session
is written with the ``mcap`` library as JSON messages on JSON-Schema channels, which Foxglove and
any MCAP reader open without our code:

| channel | one message per | content |
|---|---|---|
| ``/session`` | session (first message) | joints (id, name, model), t0 (s, CLOCK_MONOTONIC of t = 0), segment_s, measured_theta, rate_hz, prefix |
| ``/joint<ID>/cycle`` | loop cycle | t (s, monotonic: the cycle's deadline, the model's time), t_wake (s, monotonic: when the cycle woke, wrote the goal and read the servo), wall (s, Unix, of t), cycle, force (N), tau (N·m, the torque this cycle integrated), theta_model (rad), omega_model (rad/s), theta_goal (rad), theta_present (rad, null where not read), rendering_error (theta_present − theta_model, rad, null where not read), fault (the joint's fault bits), mode (the loop's mode code: 0 running, 1 holding, 2 faulted), passivity_energy (J, the passivity guard's balance), passivity_damping (N·m·s/rad, the damping it adds) |
| ``/params`` | start and each accepted change | source ("start", "set"), request, params (every live value) |
| ``/stats`` | about a second | the ``--stats-json`` object so far |
| ``/events`` | tare, warning | text |

``t`` is the CSV dataset's time base (recording.py): the loop integrates one step per deadline,
so the deadline is the model's clock. A cycle message carries the torque that cycle
integrated; the CSV row and :func:`admittance.formats.recording.load_recording` pair each angle
with the next cycle's (recording.with_next_cycle), so both files give the same dataset.

Every message's ``log_time`` is its wall-clock time (ns since the Unix epoch) and
``publish_time`` its CLOCK_MONOTONIC time (ns): the loop stamps cycles on the monotonic clock and
the wall time is that plus the offset between the two clocks, measured once, at the session's
first drain (ecosystem.Ecosystem.wall_offset_ns), so the wall times keep the cycles' order.

Chunks are :data:`CHUNK_BYTES` long (about 1.5 s of one joint at 1 kHz) and the file is
flushed after every tick, so a session cut short (SIGKILL, power loss) leaves a file that reads
back, in a streaming reader, up to its last complete chunk (admittance.formats.converters); the CSV
dataset, flushed every batch, loses less. The writer keeps one index entry per chunk in memory
until the summary is written at the close; as mcap's objects they cost about 680 bytes each, so
a recording's memory grew with its length (2.5 MB an hour of one joint at 1 kHz with 256 KiB
chunks, the writer alone). :class:`PackedChunkIndices` keeps them as the ~100 bytes the summary
will hold: the same writer then stayed flat over half an hour's messages (docs/benchmarks.md).
"""

from __future__ import annotations

import array
import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from admittance.errors import ConfigError
from admittance.formats.mcap_layout import CYCLE_SCHEMA, EVENT_SCHEMA, PARAMS_SCHEMA, SESSION_SCHEMA
from admittance.formats.recording import with_defaults

CHUNK_BYTES = 256 * 1024


class PackedChunkIndices:
    """The writer's chunk indexes, kept as the bytes the summary will hold.

    The ``mcap`` writer keeps one index entry per chunk until it writes the summary at the
    close; as ``ChunkIndex`` objects they cost about 680 bytes each, so a recording's memory
    grew with its length. Packed, about 100. The writer only appends to the list and iterates
    it once at the close, calling ``write`` on each item, which is all this offers.
    """

    class _Record:
        __slots__ = ("raw",)

        def __init__(self, raw: bytes) -> None:
            self.raw = raw

        def write(self, stream: Any) -> None:
            stream.write(self.raw)

    def __init__(self) -> None:
        from mcap.data_stream import RecordBuilder

        self._builder = RecordBuilder()
        self._data = bytearray()
        self._ends = array.array("Q")

    def append(self, index: Any) -> None:
        index.write(self._builder)
        self._data += self._builder.end()
        self._ends.append(len(self._data))

    def __len__(self) -> int:
        return len(self._ends)

    def __iter__(self) -> Iterator[_Record]:
        start = 0
        for end in self._ends:
            yield self._Record(bytes(self._data[start:end]))
            start = end


def pack_chunk_indices(writer: Any) -> bool:
    """Give ``writer`` a :class:`PackedChunkIndices` in place of its list; False (and the
    writer left as it is) when this ``mcap`` version keeps its indexes elsewhere: a test
    (tests/test_mcap_recording.py) then fails, rather than a recording losing its index."""
    name = "_Writer__chunk_indices"  # mcap 1.x: a private list, appended to per chunk
    if not isinstance(getattr(writer, name, None), list) or getattr(writer, name):
        return False
    setattr(writer, name, PackedChunkIndices())
    return True


def _nan_to_none(values: np.ndarray) -> list[float | None]:
    return [None if v != v else v for v in values.tolist()]


class McapRecorder:
    """Writes the session's MCAP; every method is called from the supervisor's thread."""

    def __init__(self, path: Path, session: dict[str, Any]) -> None:
        from mcap.writer import CompressionType, Writer

        try:
            self._fh = path.open("wb")
        except OSError as exc:
            raise ConfigError(f"record: cannot write {path} ({exc.strerror})") from None
        self.path = path
        self._writer = Writer(self._fh, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        pack_chunk_indices(self._writer)
        self._writer.start(profile="", library="admittance")
        self._encode = msgspec.json.Encoder().encode
        self._channels: dict[str, int] = {}
        self._sequence: dict[int, int] = {}
        self._schemas: dict[str, int] = {}
        self.messages = 0
        self._log("/session", SESSION_SCHEMA, session, time.monotonic_ns(), time.time_ns())
        self.flush()

    def _channel(self, topic: str, schema: dict) -> int:
        if topic not in self._channels:
            title = schema["title"]
            if title not in self._schemas:
                self._schemas[title] = self._writer.register_schema(title, "jsonschema", json.dumps(schema).encode())
            self._channels[topic] = self._writer.register_channel(topic, "json", self._schemas[title])
        return self._channels[topic]

    def _log(self, topic: str, schema: dict, message: Any, mono_ns: int, wall_ns: int) -> None:
        channel = self._channel(topic, schema)
        sequence = self._sequence.get(channel, 0)
        self._writer.add_message(channel, log_time=wall_ns, data=self._encode(message), publish_time=mono_ns,
                                 sequence=sequence)
        self._sequence[channel] = sequence + 1
        self.messages += 1

    def append(self, joint_id: int, columns: dict[str, np.ndarray], wall_offset_ns: int) -> None:
        """Every cycle of one joint (the columns of telemetry.columns_by_joint)."""
        columns = with_defaults(columns)
        present = columns["theta_present"]
        error = present - columns["theta_model"]
        t_ns = np.rint(columns["t"] * 1e9).astype(np.int64).tolist()
        rows = zip(t_ns, columns["t_wake"].tolist(), columns["cycle"].astype(np.int64).tolist(),
                   columns["force"].tolist(), columns["tau"].tolist(), columns["theta_model"].tolist(),
                   columns["omega_model"].tolist(), columns["theta_goal"].tolist(), _nan_to_none(present),
                   _nan_to_none(error), columns["fault"].astype(np.int64).tolist(),
                   columns["mode"].astype(np.int64).tolist(), columns["passivity_energy"].tolist(),
                   columns["passivity_damping"].tolist())
        topic = f"/joint{joint_id}/cycle"
        for (mono, t_wake, cycle, force, tau, theta, omega, goal, theta_present, rendering_error, fault, mode, energy,
             damping) in rows:
            wall = mono + wall_offset_ns
            self._log(topic, CYCLE_SCHEMA, {
                "t": mono * 1e-9, "t_wake": t_wake, "wall": wall * 1e-9, "cycle": cycle, "force": force, "tau": tau,
                "theta_model": theta, "omega_model": omega, "theta_goal": goal, "theta_present": theta_present,
                "rendering_error": rendering_error, "fault": fault, "mode": mode, "passivity_energy": energy,
                "passivity_damping": damping}, mono, wall)

    def params(self, source: str, params: dict[str, Any], request: dict[str, Any] | None = None) -> None:
        self._log("/params", PARAMS_SCHEMA, {"source": source, "request": request or {}, "params": params},
                  time.monotonic_ns(), time.time_ns())

    def stats(self, stats: dict[str, Any]) -> None:
        self._log("/stats", {"title": "admittance.Stats", "type": "object"}, stats, time.monotonic_ns(),
                  time.time_ns())

    def event(self, text: str) -> None:
        self._log("/events", EVENT_SCHEMA, {"text": text}, time.monotonic_ns(), time.time_ns())

    def flush(self) -> None:
        """Push the chunks completed so far to the OS (what survives a SIGKILL)."""
        self._fh.flush()

    def close(self) -> None:
        """The summary and index at the end: a seeking reader can then open it too. The file is
        closed even when the summary cannot be written (a full disk): what reached it is still
        read back by a streaming reader (admittance.formats.recording.read_recording)."""
        try:
            self._writer.finish()
        finally:
            self._fh.close()
