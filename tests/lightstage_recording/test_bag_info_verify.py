"""`lightstage bag info` on a bag with a damaged chunk exited 0 and listed
every message as intact (the messages of a chunk of bags/sim_session whose CRC no longer
matches). It now reads every chunk back by default; --no-verify says in its output
that CRCs were not checked."""
import re
import shutil
import struct
import subprocess

import pytest
from lightstage_recording import BagReader
from lightstage_recording.scan import FileScan
from helpers.recording import REPO
from helpers.suite import lightstage_command

pytestmark = pytest.mark.process

BAG = REPO / 'bags' / 'sim_session'
# the bundled bag's own count (bags/README.md: re-recorded when an interface changes)
BAG_MESSAGES = BagReader(BAG).info().message_count
CHUNK_CRC_AT = 9 + 8 + 8 + 8  # opcode, length, start time, end time, uncompressed size


def _bad_crc_copy(tmp_path):
    """bags/sim_session with the CRC of its first chunk of several messages changed; the
    copy, the damaged chunk's offset, and the bag's and that chunk's message counts."""
    bag = tmp_path / 'sim_session'
    shutil.copytree(BAG, bag)
    mcap = bag / 'sim_session_0.mcap'
    scan = FileScan(mcap)
    chunks = [(i.chunk_start_offset, i) for i in scan.summary.chunk_indexes]
    counts = [len(c.messages) for c in scan.walk()]
    damaged = next(i for i, n in enumerate(counts) if n > 2)
    offset = chunks[damaged][0]
    raw = bytearray(mcap.read_bytes())
    (crc,) = struct.unpack_from('<I', raw, offset + CHUNK_CRC_AT)
    assert crc != 0  # our writer stores chunk CRCs
    struct.pack_into('<I', raw, offset + CHUNK_CRC_AT, crc ^ 0xFFFFFFFF)
    mcap.write_bytes(bytes(raw))
    return bag, offset, sum(counts), counts[damaged]


def _info(*args):
    return subprocess.run(lightstage_command('bag', 'info', *map(str, args)), capture_output=True,
                          text=True, timeout=60)


def test_bag_info_finds_the_bad_crc_by_default(tmp_path):
    bag, offset, total, lost = _bad_crc_copy(tmp_path)
    p = _info(bag)
    assert p.returncode == 1, p.stdout + p.stderr
    assert f'Messages:          {total - lost} ' in p.stdout, p.stdout
    assert f'the chunk at byte {offset} ' in p.stdout and 'CRCValidationError' in p.stdout
    assert 'INCOMPLETE BAG' in p.stdout and 'bag recover' in p.stdout
    assert re.search(r'Checked:           every message read back from its chunk '
                     r'\(\d+ chunks, CRCs verified\)', p.stdout), p.stdout


def test_bag_info_without_verification_says_the_crcs_were_not_checked(tmp_path):
    bag, _, total, _ = _bad_crc_copy(tmp_path)
    p = _info('--no-verify', bag)
    assert p.returncode == 0, p.stderr  # the summary is intact; nothing was read to doubt it
    assert f'Messages:          {total} ' in p.stdout
    assert ("Checked:           NO: summarised from the files' summaries, chunk CRCs not "
            f'checked; `lightstage bag info {bag}` (without --no-verify) checks them') in p.stdout


def test_the_intact_bundled_bag_passes_the_check():
    p = _info(BAG)
    assert p.returncode == 0, p.stdout + p.stderr
    assert f'Messages:          {BAG_MESSAGES} ' in p.stdout and 'CRCs verified' in p.stdout
