"""The firmware builds from source with Debian's AVR toolchain, fits the chip, and its
pin assignment really is a build option."""
import re
import subprocess

import pytest

from lightstage_driver import protocol as p
from lightstage_driver.simavr_backend import SimavrBackend, firmware_dir, missing_tools

from helpers.firmware_wire import Wire

pytestmark = [pytest.mark.skipif(bool(missing_tools()), reason=f'AVR toolchain missing: {missing_tools()}'), pytest.mark.process]


def read_intel_hex(path):
    """Bytes of an Intel HEX file (checksums verified), as one contiguous image from 0."""
    image = bytearray()
    base = 0
    for number, line in enumerate(path.read_text().split(), 1):
        assert line.startswith(':'), f'line {number}: {line!r}'
        record = bytes.fromhex(line[1:])
        assert sum(record) & 0xFF == 0, f'line {number}: bad checksum'
        count, address, kind, data = record[0], record[1] << 8 | record[2], record[3], record[4:-1]
        assert len(data) == count
        if kind == 0:
            start = base + address
            image[len(image):start] = b'\xff' * max(0, start - len(image))
            image[start:start + count] = data
        elif kind == 2:
            base = (data[0] << 8 | data[1]) * 16
        elif kind == 1:
            return bytes(image)
    raise AssertionError('no end-of-file record')


def test_firmware_builds_and_fits_the_atmega328p(tmp_path):
    directory = firmware_dir()
    build = tmp_path / 'build'
    result = subprocess.run(['make', '-C', str(directory), f'BUILD={build}'], capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    match = re.search(r'flash (\d+) bytes .* RAM (\d+) bytes static', result.stdout)
    assert match, result.stdout
    flash, ram = int(match[1]), int(match[2])
    assert 1000 < flash <= 32256 - 4096        # below the bootloader, with room to grow
    # the graded-level table (16 x 32 levels) and the latch schedule (32 steps) take 773 bytes;
    # at least 512 stay for the stack, whose deepest use (stage_poll -> exposure_start ->
    # schedule_build, plus an interrupt) is ~250 bytes by avr-gcc -fstack-usage
    assert ram <= 1536
    # the .hex a user flashes is exactly the ELF's program image
    binary = tmp_path / 'image.bin'
    subprocess.run(['avr-objcopy', '-O', 'binary', '-R', '.eeprom', str(build / 'lightstage.elf'),
                    str(binary)], check=True)
    image = read_intel_hex(build / 'lightstage.hex')
    assert image == binary.read_bytes()
    assert len(image) == flash


def test_another_wiring_works_end_to_end(tmp_path):
    """Data D2, clock D3 (port D), latch A0 (port C), trigger D9 (port B): the latch and the
    trigger are on different ports, so they switch one instruction apart, the LEDs on
    just before the trigger rises and off just after it falls."""
    pins = {'data': 2, 'clock': 3, 'latch': 14, 'trigger': 9}
    backend = SimavrBackend(build_dir=tmp_path / 'build', pins=pins)
    backend.start()
    try:
        wire = Wire(backend.port)
        wire.call(p.Command.IDENTIFY, timeout_s=2.0)
        words = [0x8000_0001, 0x0F0F_0F0F, 0]
        for word in words:
            wire.set_pattern(word, show_now=True)
        wire.set_pattern(0x1234_5678, show_now=False)
        wire.fire(321)
        assert backend.wait_for(lambda w, pl: len(w) >= 5 and len(pl) >= 1, 2.0)
        assert [w.word for w in backend.led_words()] == words + [0x1234_5678, 0]
        (rise, fall), = backend.trigger_pulse_cycles()
        assert abs(fall - rise - 321 * 16) < 8
        lit, dark = backend.led_words()[-2:]
        assert 0 <= rise - round(lit.time_s * 16e6) <= 4
        assert 0 <= round(dark.time_s * 16e6) - fall <= 4
        wire.close()
    finally:
        backend.close()


def test_bad_pin_choice_is_refused_at_build_time(tmp_path):
    result = subprocess.run(['make', '-C', str(firmware_dir()), f'BUILD={tmp_path}', 'PIN_DATA=1', 'firmware'],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode != 0
    assert 'D0/D1 are the UART' in result.stderr
    result = subprocess.run(['make', '-C', str(firmware_dir()), f'BUILD={tmp_path}', 'PIN_DATA=8', 'firmware'],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode != 0
    assert 'four different pins' in result.stderr


def test_missing_sources_and_bad_firmware_are_reported_clearly(tmp_path):
    from lightstage_driver.simavr_backend import SimavrUnavailable, build_firmware
    with pytest.raises(SimavrUnavailable, match='no firmware Makefile'):
        SimavrBackend(directory=tmp_path).start()
    assert list(tmp_path.iterdir()) == []          # nothing created there
    harness, _ = build_firmware()
    bad = tmp_path / 'bad.elf'
    bad.write_bytes(b'not an ELF file')
    result = subprocess.run([str(harness), str(bad)], capture_output=True, text=True, timeout=10,
                            stdin=subprocess.DEVNULL)
    assert result.returncode == 1
    assert f"cannot read firmware '{bad}'" in result.stderr
    assert 'PTY' not in result.stdout
