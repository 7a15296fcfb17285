"""camera_info_url: camera_calibration's YAML, or uncalibrated; bad files named with the reason."""
import pytest
import yaml

from lightstage_camera.camera_info import Calibration, load_calibration, url_path

GOOD = {'image_width': 64, 'image_height': 48, 'camera_name': 'stage_cam',
        'camera_matrix': {'rows': 3, 'cols': 3, 'data': [100.0, 0, 32, 0, 100, 24, 0, 0, 1]},
        'distortion_model': 'plumb_bob',
        'distortion_coefficients': {'rows': 1, 'cols': 5, 'data': [0.1, -0.01, 0, 0, 0]},
        'rectification_matrix': {'rows': 3, 'cols': 3, 'data': [1, 0, 0, 0, 1, 0, 0, 0, 1]},
        'projection_matrix': {'rows': 3, 'cols': 4, 'data': [100, 0, 32, 0, 0, 100, 24, 0, 0, 0, 1, 0]}}


def test_a_camera_calibration_yaml_loads_from_a_path_or_file_url(tmp_path):
    path = tmp_path / 'cam one.yaml'
    path.write_text(yaml.safe_dump(GOOD))
    for url in (str(path), f'file://{path.as_posix().replace(" ", "%20")}'):
        cal = load_calibration(url)
        assert (cal.width, cal.height, cal.distortion_model) == (64, 48, 'plumb_bob')
        assert cal.k[0] == 100.0 and cal.d == (0.1, -0.01, 0.0, 0.0, 0.0) and len(cal.p) == 12
    assert load_calibration('') is None
    assert cal.for_image(64, 48) is cal
    with pytest.raises(ValueError, match='is for 64x48 images, the camera delivers 120x120'):
        cal.for_image(120, 120)
    assert Calibration.uncalibrated(120, 100).k == (0.0,) * 9


@pytest.mark.parametrize('change, message', [
    ({'camera_matrix': {'rows': 3, 'cols': 3, 'data': [1, 2, 3]}}, 'camera_matrix must be 3x3'),
    ({'image_width': None}, 'not a camera calibration'),
    ({'projection_matrix': None}, 'projection_matrix is missing'),
    ({'image_height': 0}, 'image size 64x0 is not valid'),
])
def test_a_file_that_is_not_a_calibration_is_refused_with_the_reason(tmp_path, change, message):
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump({**GOOD, **change}))
    with pytest.raises(ValueError, match=message):
        load_calibration(str(path))


def test_missing_files_and_unknown_schemes_are_refused(tmp_path):
    with pytest.raises(OSError):
        load_calibration(str(tmp_path / 'none.yaml'))
    with pytest.raises(ValueError, match='use file:///path/to/camera.yaml'):
        url_path('http://example.invalid/cam.yaml')
