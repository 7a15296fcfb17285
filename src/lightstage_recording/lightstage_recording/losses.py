"""What a recording lost on the way, from what it holds: the recorder's report and `lightstage
bag info` count it the same way (`LossCounter`).

- **Sequence gaps.** Every message is stored with its publisher's DDS publication sequence
  number (+1 per message the publisher sends; `BagMessage.sequence`). On a topic with one
  publisher -- the stage's: /illumination, /camera/image_raw, /camera/camera_info,
  /lightstage/result, the service event topics -- a jump from n to n + k means k - 1 messages
  the publisher sent never reached the bag (a recorder that was stopped or too slow: the
  publisher's keep-last history dropped them). Topics with several publishers (/rosout,
  /diagnostics, /parameter_events) interleave several counters and are not counted: those
  that had several when the recorder found them, and any whose numbers go backwards (a second
  publisher came, or the one started again) -- from then on the topic is not counted at all,
  since its jumps are no longer losses; sequence 0 means the writer stored none (not counted).
- **Unmatched service events.** A service with introspection on publishes one event when its
  server receives a request and one when it sends the response (`REQUEST_RECEIVED`,
  `RESPONSE_SENT`; a client with introspection: `REQUEST_SENT`, `RESPONSE_RECEIVED`), both
  with the client's GID and the call's sequence number. A request whose response is not in
  the bag, or a response whose request is not, is counted (a call still running when the
  recording ended counts too).

Pure Python: the event's `service_msgs/ServiceEventInfo` is read from the CDR bytes
(`event_info`), no rclpy.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field

from .msg_definitions import is_service_event

REQUEST_SENT, REQUEST_RECEIVED, RESPONSE_SENT, RESPONSE_RECEIVED = range(4)
_ANSWERS = {REQUEST_RECEIVED: RESPONSE_SENT, REQUEST_SENT: RESPONSE_RECEIVED}
_ASKS = {v: k for k, v in _ANSWERS.items()}


def event_info(data: bytes) -> tuple[int, bytes, int] | None:
    """(event_type, client_gid, sequence_number) of a serialized ``pkg/srv/Name_Event`` (its
    first field, ``service_msgs/ServiceEventInfo info``), None if the bytes are not one.

    CDR: a 4-byte encapsulation header (byte 1: 0 big-, 1 little-endian XCDR1; 6 / 7 XCDR2),
    then uint8 event_type, builtin_interfaces/Time stamp (int32, uint32) at 4, char[16]
    client_gid at 12, int64 sequence_number at 32 (XCDR1 aligns it to 8; XCDR2 to 4: 28)."""
    if len(data) < 4 + 40:
        return None
    kind = data[1]
    if data[0] != 0 or kind not in (0, 1, 6, 7):
        return None
    endian = '<' if kind in (1, 7) else '>'
    body = data[4:]
    seq_at = 32 if kind in (0, 1) else 28
    event_type = body[0]
    if event_type > RESPONSE_RECEIVED:
        return None
    return event_type, bytes(body[12:28]), struct.unpack_from(f'{endian}q', body, seq_at)[0]


@dataclass
class _Topic:
    counted: bool               # one publisher: its sequence numbers are one counter
    received: int = 0
    missing: int = 0
    last: int | None = None


@dataclass
class _Service:
    pending: dict = field(default_factory=dict)  # (side, gid, seq) -> 1, requests not answered
    responses_alone: int = 0
    calls: int = 0
    unreadable: int = 0

    @property
    def requests_alone(self) -> int:
        return len(self.pending)


class LossCounter:
    """Sequence gaps per topic and unmatched service events per service; see the module.
    Feed every message in the order it was received (`message`), then read `gaps`,
    `unmatched`, `to_json` or `lines`."""

    def __init__(self):
        self._topics: dict[str, _Topic] = {}
        self._services: dict[str, _Service] = {}

    def add_topic(self, topic: str, type_name: str, publishers: int) -> None:
        """A topic and how many publishers it had when it was found (1: gaps are counted)."""
        if topic not in self._topics:
            self._topics[topic] = _Topic(counted=publishers == 1)
            if is_service_event(topic, type_name):
                self._services[topic] = _Service()

    def message(self, topic: str, sequence: int, data: bytes = b'') -> None:
        t = self._topics.get(topic)
        if t is None:
            return
        t.received += 1
        if t.counted and sequence:
            if t.last is not None and sequence <= t.last:
                t.counted, t.missing = False, 0  # several publishers, or a restart
            else:
                if t.last is not None and sequence > t.last + 1:
                    t.missing += sequence - t.last - 1
                t.last = sequence
        s = self._services.get(topic)
        if s is not None:
            self._service_event(s, data)

    @staticmethod
    def _service_event(s: _Service, data: bytes) -> None:
        info = event_info(data)
        if info is None:
            s.unreadable += 1
            return
        event_type, gid, seq = info
        if event_type in _ANSWERS:
            s.pending[(event_type, gid, seq)] = 1
            s.calls += 1
        elif s.pending.pop((_ASKS[event_type], gid, seq), None) is None:
            s.responses_alone += 1
            s.calls += 1

    # -- results
    @property
    def gaps(self) -> dict[str, tuple[int, int]]:
        """topic -> (messages missing, messages received), for topics that lost some."""
        return {name: (t.missing, t.received) for name, t in self._topics.items() if t.missing}

    @property
    def unmatched(self) -> dict[str, tuple[int, int]]:
        """service event topic -> (requests without response, responses without request)."""
        return {name: (s.requests_alone, s.responses_alone) for name, s in self._services.items()
                if s.requests_alone or s.responses_alone}

    @property
    def uncounted(self) -> list[str]:
        """Topics whose gaps are not counted (several publishers, or one that restarted)."""
        return sorted(name for name, t in self._topics.items() if not t.counted)

    @property
    def lost_any(self) -> bool:
        return bool(self.gaps or self.unmatched)

    def to_json(self) -> dict:
        return {'sequence_gaps': {name: {'missing': m, 'received': r}
                                  for name, (m, r) in sorted(self.gaps.items())},
                'unmatched_service_events': {
                    name: {'requests_without_response': q, 'responses_without_request': a}
                    for name, (q, a) in sorted(self.unmatched.items())},
                'gaps_not_counted': self.uncounted}

    def lines(self) -> list[str]:
        """What was lost, one line per topic / service ([] if nothing was)."""
        out = []
        for name, (missing, received) in sorted(self.gaps.items()):
            out.append(f'{name}: {missing} of {missing + received} messages missing (publisher '
                       'sequence numbers skipped: sent, never recorded)')
        for name, (requests, responses) in sorted(self.unmatched.items()):
            parts = []
            if requests:
                parts.append(f'{requests} request{"s" if requests != 1 else ""} without response')
            if responses:
                parts.append(f'{responses} response{"s" if responses != 1 else ""} without request')
            out.append(f'{name}: {", ".join(parts)}')
        return out
