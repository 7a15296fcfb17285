"""Byte-exact framing, CRC and payloads of docs/PROTOCOL.md."""
import struct

import pytest

from lightstage_driver import protocol as p
from lightstage_driver.errors import ChecksumError, FramingError, PayloadError


def test_crc_check_value_is_ccitt_false():
    assert p.crc16_ccitt(b'123456789') == 0x29B1
    assert p.crc16_ccitt(b'') == 0xFFFF


def test_documented_example_frames_are_byte_exact():
    assert p.encode_frame(1, p.Command.SET_PATTERN, p.pack_set_pattern(0x0F, True)) == \
        bytes.fromhex('A5 05 01 03 01 0F 00 00 00 BE 71')
    assert p.encode_frame(1, p.Command.IDENTIFY) == bytes.fromhex('A5 00 01 01 8C EF')


def test_frame_roundtrip_and_layout():
    frame = p.encode_frame(200, p.Command.FIRE, p.pack_u32(30000))
    assert frame[0] == p.SOF and frame[1] == 4 and frame[2] == 200 and frame[3] == p.Command.FIRE
    assert struct.unpack('<I', frame[4:8])[0] == 30000
    assert struct.unpack('<H', frame[8:])[0] == p.crc16_ccitt(frame[1:8])
    assert p.decode_frame(frame) == p.Frame(200, p.Command.FIRE, p.pack_u32(30000))


def test_longest_frame_fits_and_longer_is_refused():
    entries = [p.SequenceEntry(1 << k, 20 + k) for k in range(p.MAX_SEQUENCE)]
    payload = p.pack_sequence(1000, entries)
    assert len(payload) == 5 + 8 * p.MAX_SEQUENCE <= p.MAX_PAYLOAD
    frame = p.encode_frame(7, p.Command.RUN_SEQUENCE, payload)
    assert len(frame) <= p.MAX_FRAME
    decoded = p.decode_frame(frame)
    gap, count = p.unpack_sequence_header(decoded.payload)
    assert (gap, count) == (1000, p.MAX_SEQUENCE)
    assert p.unpack_sequence_entries(decoded.payload, count) == entries
    with pytest.raises(PayloadError, match='MAX_PAYLOAD'):
        p.encode_frame(1, p.Command.RUN_SEQUENCE, bytes(p.MAX_PAYLOAD + 1))


@pytest.mark.parametrize('mutate, error, match', [
    (lambda f: f[:-1], FramingError, 'LEN'),
    (lambda f: b'\x00' + f[1:], FramingError, 'SOF'),
    (lambda f: f[:-1] + bytes([f[-1] ^ 0x40]), ChecksumError, 'CRC mismatch'),
    (lambda f: f[:5] + bytes([f[5] ^ 1]) + f[6:], ChecksumError, 'CRC mismatch'),
    (lambda f: f[:3], FramingError, 'shorter'),
])
def test_decode_frame_names_the_defect(mutate, error, match):
    frame = p.encode_frame(3, p.Command.SET_PATTERN, p.pack_set_pattern(0xFFFF0000, False))
    with pytest.raises(error, match=match):
        p.decode_frame(mutate(frame))


def test_stream_decoder_splits_joins_and_resyncs():
    a = p.encode_frame(1, p.Command.IDENTIFY)
    b = p.encode_frame(2, p.Command.FIRE, p.pack_u32(100))
    c = p.encode_frame(3, p.Command.ALL_OFF)
    corrupted = bytearray(b)
    corrupted[5] ^= 0xFF
    stream = b'\x00\xa5\x99garbage' + a + bytes(corrupted) + c
    decoder = p.FrameDecoder()
    out = []
    for i in range(len(stream)):          # one byte at a time
        out += decoder.feed(stream[i:i + 1], now=0.0)
    frames = [item for item in out if isinstance(item, p.Frame)]
    bad = [item for item in out if isinstance(item, p.BadFrame)]
    assert [f.seq for f in frames] == [1, 3]
    assert [(x.seq, x.cmd) for x in bad] == [(2, p.Command.FIRE)]
    assert decoder.crc_errors == 1
    assert decoder.length_errors == 1     # the stray A5 99 claimed 153 payload bytes


def test_the_host_skips_a_corrupted_frame_whole_and_not_a_sof_in_its_payload():
    # a reply whose payload holds 0xA5 and whose CRC fails, then the next reply: rescanning
    # from the byte after its SOF reads 'A5 30 ...' as a frame of 48 payload bytes and waits
    # for them (the host has no inter-byte timeout); skipping the frame by its LEN does not
    corrupted = bytearray(p.encode_frame(7, p.Command.HEARTBEAT | p.REPLY_BIT,
                                         bytes([0xA5, 0x30, 1, 2, 3, 4, 5])))
    corrupted[-1] ^= 0x01
    following = p.encode_frame(8, p.Command.HEARTBEAT | p.REPLY_BIT, bytes(7))
    rescan, host = (p.FrameDecoder(inter_byte_timeout_s=float('inf'), skip_bad_frames=skip)
                    for skip in (False, True))
    for decoder in (rescan, host):
        assert [type(x) for x in decoder.feed(bytes(corrupted), now=0.0)] == [p.BadFrame]
    assert rescan.feed(following, now=1.0) == []            # stuck behind the phantom frame
    assert host.feed(following, now=1.0) == [p.Frame(8, p.Command.HEARTBEAT | p.REPLY_BIT, bytes(7))]
    # garbage after a corrupted frame (its LEN may be wrong too): the byte-by-byte rescan
    decoder = p.FrameDecoder(skip_bad_frames=True)
    stream = bytes(corrupted[:4]) + b'\x00' + bytes(corrupted[5:]) + b'\x11' + following
    out = decoder.feed(stream, now=0.0)
    assert out[-1] == p.Frame(8, p.Command.HEARTBEAT | p.REPLY_BIT, bytes(7))


def test_stream_decoder_drops_a_stalled_frame_after_the_inter_byte_timeout():
    decoder = p.FrameDecoder()
    frame = p.encode_frame(9, p.Command.HEARTBEAT)
    assert decoder.feed(frame[:3], now=0.0) == []
    # the rest never comes; a new frame arrives after the line was quiet > 10 ms
    out = decoder.feed(p.encode_frame(10, p.Command.HEARTBEAT), now=0.05)
    assert out == [p.Frame(10, p.Command.HEARTBEAT)]
    assert decoder.timeouts >= 1


def test_identity_roundtrip_and_bad_payloads():
    ident = p.Identity(1, (1, 2, 3), 32, 8, 4, 8, 20, 2_000_000, 1000, 16, 136, 'lightstage-avr')
    packed = ident.pack()
    assert len(packed) == 20 + len('lightstage-avr')
    assert p.Identity.unpack(packed) == ident
    with pytest.raises(PayloadError, match='identity payload'):
        p.Identity.unpack(packed[:10])
    with pytest.raises(PayloadError, match='not ASCII'):
        p.Identity.unpack(packed[:20] + b'\xff')


def test_status_nak_and_events_roundtrip():
    status = p.Status(123456, True, False, True, 7)
    assert p.Status.unpack(status.pack()) == status
    nak = p.Nak(p.Command.FIRE, p.NakReason.EXPOSURE_RANGE, 5)
    assert p.Nak.unpack(nak.pack()) == nak
    assert 'FIRE' in nak.describe() and 'EXPOSURE_RANGE' in nak.describe() and 'value 5' in nak.describe()
    assert 'unknown reason' in p.Nak(1, 200, 0).describe()
    event = p.TriggerEvent(3, 0xFFFFFFF0, 10)
    assert p.TriggerEvent.unpack(event.pack()) == event
    assert p.SequenceDone.unpack(p.SequenceDone(2, 1).pack()) == p.SequenceDone(2, 1)
    flags, levels = p.unpack_set_levels(p.pack_set_levels(list(range(32)), True))
    assert flags == p.SHOW_NOW and levels == tuple(range(32))


def test_line_time_of_a_frame():
    # 11 bytes at 115200 8N1: 110 bits
    assert p.line_seconds(p.frame_bytes(5), 115200) == pytest.approx(110 / 115200)
