"""Camera calibration for ``camera_info``: the YAML that ROS's ``camera_calibration`` writes
(``camera_info_manager``'s format), or an uncalibrated default.

`load_calibration(url)` reads ``file:///path/cam.yaml``, ``/path/cam.yaml`` or
``package://pkg/path`` (through ament_index when available); an empty url gives None (the
node then publishes an uncalibrated camera_info: zero K/P, no distortion, the image's size,
as camera_info_manager does). No rclpy here: the node copies the fields into its message.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote, urlparse

import yaml

SIZES = {'camera_matrix': (3, 3), 'rectification_matrix': (3, 3), 'projection_matrix': (3, 4)}


@dataclass(frozen=True)
class Calibration:
    """One camera's intrinsics, as ``sensor_msgs/CameraInfo`` holds them (row-major lists)."""
    width: int
    height: int
    camera_name: str = ''
    distortion_model: str = ''
    d: tuple = ()
    k: tuple = (0.0,) * 9
    r: tuple = (0.0,) * 9
    p: tuple = (0.0,) * 12
    source: str = field(default='', compare=False)

    @classmethod
    def uncalibrated(cls, width: int, height: int) -> 'Calibration':
        return cls(int(width), int(height))

    def for_image(self, width: int, height: int) -> 'Calibration':
        """This calibration, checked against an image's size (ValueError if it differs)."""
        if (self.width, self.height) != (int(width), int(height)):
            raise ValueError(f'calibration {self.source or ""} is for {self.width}x{self.height} '
                             f'images, the camera delivers {width}x{height}: recalibrate, or '
                             'set camera_info_url to the calibration of this image size')
        return self


def url_path(url: str) -> Path:
    """The file a camera_info_url names."""
    parsed = urlparse(url)
    if parsed.scheme in ('', 'file'):
        return Path(unquote(parsed.path if parsed.scheme else url)).expanduser()
    if parsed.scheme == 'package':
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory(parsed.netloc)) / parsed.path.lstrip('/')
    raise ValueError(f'camera_info_url {url!r}: use file:///path/to/camera.yaml, a plain path '
                     'or package://package/path')


def _matrix(data: dict, key: str) -> tuple:
    rows, cols = SIZES[key]
    entry = data.get(key)
    if entry is None:
        raise ValueError(f'{key} is missing')
    values = entry.get('data') if isinstance(entry, dict) else None
    if (not isinstance(values, list) or len(values) != rows * cols
            or (isinstance(entry, dict) and (entry.get('rows', rows), entry.get('cols', cols)) != (rows, cols))):
        raise ValueError(f'{key} must be {rows}x{cols} (rows, cols, data with {rows * cols} numbers)')
    return tuple(float(v) for v in values)


def load_calibration(url: str) -> Calibration | None:
    """The calibration a camera_info_url names (None for an empty url); ValueError or
    OSError naming the file and what is wrong with it."""
    if not str(url).strip():
        return None
    path = url_path(str(url).strip())
    text = path.read_text()
    try:
        data = yaml.safe_load(text)
        if not isinstance(data, dict):
            raise ValueError('not a YAML mapping')
        d_entry = data.get('distortion_coefficients') or {'data': []}
        calibration = Calibration(
            width=int(data['image_width']), height=int(data['image_height']),
            camera_name=str(data.get('camera_name', '')),
            distortion_model=str(data.get('distortion_model', 'plumb_bob')),
            d=tuple(float(v) for v in d_entry.get('data') or []),
            k=_matrix(data, 'camera_matrix'), r=_matrix(data, 'rectification_matrix'),
            p=_matrix(data, 'projection_matrix'), source=str(path))
    except (KeyError, TypeError, ValueError, yaml.YAMLError) as exc:
        raise ValueError(f'{path} is not a camera calibration (camera_calibration\'s YAML: '
                         f'image_width, image_height, camera_matrix, distortion_coefficients, '
                         f'rectification_matrix, projection_matrix): {exc}') from exc
    if calibration.width < 1 or calibration.height < 1:
        raise ValueError(f'{path}: image size {calibration.width}x{calibration.height} is not valid')
    return calibration
