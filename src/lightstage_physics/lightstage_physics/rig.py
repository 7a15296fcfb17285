"""The light stage as data: illumination sites, LED channels and the camera of a capture.

The rig conventions: the LED layout Pattern.msg fixes (the channels and their order
`CHANNELS`, the paper's stage size `N_SITES`, `N_LEDS`, the site-major LED order
``led = site * 4 + channel``, `led_index`, `site_and_channel`, the number of site patterns
`n_site_subsets`) is `lightstage_graph.leds`, which the driver shares; this module takes
it from there and adds the physics on top: the per-colour expansion of site patterns
(`site_to_led_patterns`), the authors' `DEFAULT_DIMMER` and the rig description `Rig`.
"""
from __future__ import annotations

import difflib
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import yaml
from lightstage_graph.leds import (CHANNELS, N_CHANNELS, N_LEDS, N_SITES,  # noqa: F401 (the rig's names)
                                   WAVELENGTHS_NM, channel_index, led_index, n_site_subsets,
                                   site_and_channel)
from lightstage_graph.limits import (EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN,
                                     check_range)

# The authors' scale of the single-LED images before multiplexing, so that many lit LEDs do
# not saturate. Renders, the simulated camera and the training all use it; a classifier is
# only right for images taken at the dimmer it was trained with (its artifact records it).
DEFAULT_DIMMER = 0.45


def site_to_led_patterns(site_patterns, n_channels: int = N_CHANNELS) -> np.ndarray:
    """(n_sites, m) site matrix -> (n_sites * n_channels, n_channels * m) LED matrix (float32).

    The paper's per-colour mode: site-pattern column j gives one image per channel, in
    channel order; image ``n_channels * j + c`` lights LED ``site * n_channels + c`` of every
    site lit in column j.
    """
    W = np.asarray(site_patterns, dtype=np.float32)
    if W.ndim != 2:
        raise ValueError(f"site patterns must be a matrix (n_sites, m), got shape {W.shape}")
    n_sites, m = W.shape
    P = np.zeros((n_sites, n_channels, m, n_channels), dtype=np.float32)
    for c in range(n_channels):
        P[:, c, :, c] = W
    return P.reshape(n_sites * n_channels, m * n_channels)


def _yaml_number(value, key: str, source: str, whole: bool = False) -> float | int:
    """A finite number (`whole`: a whole number) of a rig.yaml entry, else ValueError naming
    the key and value. 11.9 is refused where a whole number belongs, not truncated (a bit
    depth or an image size off by a fraction is a typo, not a setting). Numeric strings are
    taken: YAML 1.1 reads `3e4` (no decimal point) as a string."""
    if whole and isinstance(value, int) and not isinstance(value, bool):
        return value
    if not isinstance(value, bool):
        try:
            number = float(value)
        except (TypeError, ValueError, OverflowError):
            pass
        else:
            if number.is_integer() if whole else math.isfinite(number):
                return int(number) if whole else number
    raise ValueError(f"{source}: {key} must be a {'whole' if whole else 'finite'} number, "
                     f"got {value!r}")


MAX_FRAMES_AVERAGED = 100_000
MAX_IMAGE_SIDE = 16_384
# (field, lo, hi, unit): the camera values of a rig, as rig.yaml's camera section gives them
RIG_RANGES = (("exposure_us", EXPOSURE_US_MIN, EXPOSURE_US_MAX, "us"),
              ("gain_db", GAIN_DB_MIN, GAIN_DB_MAX, "dB"),
              ("camera_height_mm", 1.0, 100_000.0, "mm"),
              ("field_of_view_mm", 0.1, 100_000.0, "mm"))
RIG_KEYS = ("sites", "channels", "camera")
CAMERA_KEYS = ("bit_depth", "image_height", "image_width", "exposure_us", "gain_db",
               "frames_averaged", "height_mm", "field_of_view_mm")


def _unknown_keys(mapping: dict, known, where: str, source: str) -> None:
    """ValueError naming keys of `mapping` that are not `known` (a typo must not silently
    become a default), with the closest known key."""
    for key in mapping:
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = f"did you mean '{where}{close[0]}'?" if close else f"known: {', '.join(known)}"
            raise ValueError(f"{source}: unknown key '{where}{key}' ({hint})")


@dataclass(frozen=True)
class Site:
    """One illumination site: a diffused cluster of the four LEDs, position in mm.

    The object sits at the origin on the stage floor (z = 0); the camera looks down the z axis.
    """
    name: str
    x_mm: float
    y_mm: float
    z_mm: float

    @property
    def position_mm(self) -> tuple[float, float, float]:
        return (self.x_mm, self.y_mm, self.z_mm)


@dataclass
class Rig:
    """Sites, channels and the camera settings a capture was made with."""
    sites: list[Site]
    channels: tuple[str, ...] = CHANNELS
    wavelengths_nm: dict[str, float] = field(default_factory=lambda: dict(WAVELENGTHS_NM))
    bit_depth: int = 10
    image_size: tuple[int, int] = (240, 240)  # (height, width) in pixels
    exposure_us: float = 30000.0
    gain_db: float = 15.0
    frames_averaged: int = 16
    camera_height_mm: float = 240.0
    field_of_view_mm: float = 160.0  # side of the square working area seen by the camera

    def __post_init__(self) -> None:
        self.channels = tuple(self.channels)
        if self.channels != CHANNELS:
            raise ValueError(f"channels must be {CHANNELS} in that order, got {self.channels}")
        missing = [c for c in self.channels if c not in self.wavelengths_nm]
        if missing:
            raise ValueError(f"wavelengths_nm lacks channels {missing}")
        if not 8 <= self.bit_depth <= 16:
            raise ValueError(f"bit_depth must be 8..16, got {self.bit_depth}")
        self.image_size = (int(self.image_size[0]), int(self.image_size[1]))
        if min(self.image_size) < 1:
            raise ValueError(f"image_size must be positive, got {self.image_size}")
        if not self.sites:
            raise ValueError("a rig needs at least one illumination site")
        for name, lo, hi, unit in RIG_RANGES:
            setattr(self, name, check_range(getattr(self, name), name, lo, hi, unit))
        if not 1 <= self.frames_averaged <= MAX_FRAMES_AVERAGED:
            raise ValueError(f"frames_averaged = {self.frames_averaged} is out of range: give "
                             f"1 .. {MAX_FRAMES_AVERAGED} frames")
        if max(self.image_size) > MAX_IMAGE_SIDE:
            raise ValueError(f"image_size {self.image_size} is out of range: give 1 .. "
                             f"{MAX_IMAGE_SIDE} px per side")

    @property
    def n_sites(self) -> int:
        return len(self.sites)

    @property
    def n_leds(self) -> int:
        return self.n_sites * N_CHANNELS

    @property
    def max_level(self) -> int:
        """Largest gray level of the camera (1023 for 10 bits)."""
        return (1 << self.bit_depth) - 1

    @property
    def exposure_ms(self) -> float:
        return self.exposure_us / 1000.0

    def site_positions_mm(self) -> np.ndarray:
        """(n_sites, 3) positions in mm."""
        return np.array([s.position_mm for s in self.sites], dtype=np.float64)

    @classmethod
    def paper_default(cls, image_size: int | tuple[int, int] = 240) -> "Rig":
        """The paper's stage: five legs, radius 223 mm, height 240 mm, sites on four legs.

        Sites 0..3 sit on the lower leg segments (low elevation, near-grazing light),
        sites 4..7 on the upper segments of the same legs; the fifth leg carries no site.
        The exact mounting heights are not in the paper; these are read off its figure.
        """
        radius_mm, height_mm = 223.0, 240.0
        leg_azimuths_deg = [0.0, 72.0, 144.0, 216.0]  # four of the five legs
        lower = (radius_mm * 0.95, 0.30 * height_mm)  # (radius, height) on the lower segment
        upper = (radius_mm * 0.62, 0.78 * height_mm)
        sites = []
        for segment, (r, z) in (("lower", lower), ("upper", upper)):
            for leg, az in enumerate(leg_azimuths_deg):
                a = math.radians(az)
                sites.append(Site(f"leg{leg}_{segment}", round(r * math.cos(a), 3),
                                  round(r * math.sin(a), 3), round(z, 3)))
        size = (image_size, image_size) if isinstance(image_size, int) else tuple(image_size)
        return cls(sites=sites, image_size=size, camera_height_mm=height_mm)

    # ---- YAML -------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {
            "sites": [asdict(s) for s in self.sites],
            "channels": [{"name": c, "wavelength_nm": float(self.wavelengths_nm[c])}
                         for c in self.channels],
            "camera": {
                "bit_depth": int(self.bit_depth),
                "image_height": int(self.image_size[0]),
                "image_width": int(self.image_size[1]),
                "exposure_us": float(self.exposure_us),
                "gain_db": float(self.gain_db),
                "frames_averaged": int(self.frames_averaged),
                "height_mm": float(self.camera_height_mm),
                "field_of_view_mm": float(self.field_of_view_mm),
            },
        }

    @classmethod
    def from_dict(cls, data: dict, source: str = "rig") -> "Rig":
        """A rig from its YAML mapping; ValueError naming the key and value of any wrong entry."""
        def need(mapping, key, where):
            if not isinstance(mapping, dict) or key not in mapping:
                raise ValueError(f"{source}: missing key '{where}{key}'")
            return mapping[key]

        def entries(key):
            value = need(data, key, "")
            if not isinstance(value, list):
                raise ValueError(f"{source}: '{key}' must be a list, got {value!r}")
            return value

        def number(mapping, key, where, default=None, whole=False):
            value = need(mapping, key, where) if default is None else mapping.get(key, default)
            return _yaml_number(value, f"{where}{key}", source, whole)

        sites = [Site(str(need(s, "name", f"sites[{i}].")), number(s, "x_mm", f"sites[{i}]."),
                      number(s, "y_mm", f"sites[{i}]."), number(s, "z_mm", f"sites[{i}]."))
                 for i, s in enumerate(entries("sites"))]
        channel_entries = entries("channels")
        names = tuple(str(need(c, "name", f"channels[{i}].")) for i, c in enumerate(channel_entries))
        unknown = [n for n in names if n not in CHANNELS]
        if unknown:
            raise ValueError(f"{source}: unknown channel(s) {unknown}; "
                             f"channels must be {list(CHANNELS)}")
        wavelengths = {name: number(c, "wavelength_nm", f"channels[{i}].")
                       for i, (name, c) in enumerate(zip(names, channel_entries))}
        _unknown_keys(data, RIG_KEYS, "", source)
        cam = need(data, "camera", "")
        if not isinstance(cam, dict):
            raise ValueError(f"{source}: 'camera' must be a mapping of camera settings, got {cam!r}")
        _unknown_keys(cam, CAMERA_KEYS, "camera.", source)
        try:
            return cls(
                sites=sites, channels=names, wavelengths_nm=wavelengths,
                bit_depth=number(cam, "bit_depth", "camera.", whole=True),
                image_size=(number(cam, "image_height", "camera.", whole=True),
                            number(cam, "image_width", "camera.", whole=True)),
                exposure_us=number(cam, "exposure_us", "camera."),
                gain_db=number(cam, "gain_db", "camera."),
                frames_averaged=number(cam, "frames_averaged", "camera.", default=1, whole=True),
                camera_height_mm=number(cam, "height_mm", "camera.", default=240.0),
                field_of_view_mm=number(cam, "field_of_view_mm", "camera.", default=160.0),
            )
        except ValueError as exc:  # range checks of __post_init__
            message = str(exc)
            for name, key in (("camera_height_mm", "height_mm"), ("exposure_us", "exposure_us"),
                              ("gain_db", "gain_db"), ("frames_averaged", "frames_averaged"),
                              ("field_of_view_mm", "field_of_view_mm")):
                if message.startswith(f"{name} "):  # the key as rig.yaml spells it
                    message = f"camera.{key}{message[len(name):]}"
            raise ValueError(message if message.startswith(source) else f"{source}: {message}") \
                from None

    def save_yaml(self, path: str | Path) -> None:
        Path(path).write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))

    @classmethod
    def load_yaml(cls, path: str | Path) -> "Rig":
        path = Path(path)
        data = yaml.safe_load(path.read_text())
        if not isinstance(data, dict):
            raise ValueError(f"{path}: expected a YAML mapping with sites, channels, camera")
        return cls.from_dict(data, source=str(path))
