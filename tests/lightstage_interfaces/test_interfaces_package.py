"""The installed lightstage_interfaces package: what a full ROS install's tools and the
recorder expect is in the venv, it matches the source, and it imports with no ROS
environment variables set."""
import subprocess
import sys
from pathlib import Path

import pytest

from helpers.suite import REPO

pytestmark = pytest.mark.process

SRC = REPO / 'src' / 'lightstage_interfaces'
PREFIX = Path(sys.prefix)
SHARE = PREFIX / 'share' / 'lightstage_interfaces'
REBUILD = f'rebuild it: {sys.executable} -m pip install --no-build-isolation --no-deps --force-reinstall {SRC}'


def _definitions():
    return sorted(p.relative_to(SRC) for kind in ('msg', 'srv', 'action') for p in (SRC / kind).iterdir())


def test_share_holds_package_xml_index_marker_and_definitions():
    assert (PREFIX / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'lightstage_interfaces').is_file()
    assert (SHARE / 'package.xml').read_text() == (SRC / 'package.xml').read_text(), REBUILD
    for rel in _definitions():
        installed = SHARE / rel
        assert installed.is_file(), f'{installed} missing; {REBUILD}'
        assert installed.read_text() == (SRC / rel).read_text(), f'{rel} changed since the build; {REBUILD}'


def test_types_import_and_serialize_in_a_clean_environment():
    code = (
        'from lightstage_interfaces.msg import IlluminationState, Pattern, ClassificationResult\n'
        'from lightstage_interfaces.srv import ApplyPatterns, Classify\n'
        'from lightstage_interfaces.action import Train, CaptureModel\n'
        'from rclpy.serialization import serialize_message, deserialize_message\n'
        'm = IlluminationState(sequence=7); m.intensities[31] = 0.25\n'
        'back = deserialize_message(serialize_message(m), IlluminationState)\n'
        'assert back.sequence == 7 and back.intensities[31] == 0.25 and len(back.intensities) == 32\n'
        'assert Train.Feedback().stage == "" and CaptureModel.Result().images_captured == 0\n'
        'print("ok")\n')
    # no ROS variables at all (no sourcing, no AMENT_PREFIX_PATH, no LD_LIBRARY_PATH)
    p = subprocess.run([sys.executable, '-c', code], env={'PATH': '/usr/bin:/bin'},
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 0 and p.stdout.strip() == 'ok', p.stderr


def test_every_definition_file_is_generated():
    # a new .msg/.srv/.action must be listed in rosidl_generate_interfaces, or it is not built
    text = (SRC / 'CMakeLists.txt').read_text()
    listed = text[text.index('rosidl_generate_interfaces(${PROJECT_NAME}'):]
    for rel in _definitions():
        assert f'"{rel}"' in listed, f'{rel} is not in rosidl_generate_interfaces in CMakeLists.txt'
