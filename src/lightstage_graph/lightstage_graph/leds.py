"""The stage's LED layout, as Pattern.msg fixes it: every package numbers LEDs this way.

8 illumination sites of 4 LEDs each (red 615 nm, green 515 nm, blue 460 nm, NIR 850 nm),
numbered site-major: ``led = site * 4 + channel``. A pattern message carries 32 drives in
this order; the driver checks them, the firmware lights them, the camera's simulation renders
them, the trainer searches over them. Here (and not in the physics package) because the
driver, which depends only on this package, must name an LED's site and channel too.
`lightstage_physics.rig` builds the rig description on these. No rclpy, no NumPy here.
"""
from __future__ import annotations

__all__ = ["CHANNELS", "WAVELENGTHS_NM", "N_CHANNELS", "N_SITES", "N_LEDS", "channel_index",
           "led_index", "site_and_channel", "n_site_subsets"]

CHANNELS: tuple[str, ...] = ("red", "green", "blue", "nir")
WAVELENGTHS_NM: dict[str, float] = {"red": 615.0, "green": 515.0, "blue": 460.0, "nir": 850.0}
N_CHANNELS = len(CHANNELS)
N_SITES = 8  # the paper's stage: 8 illumination sites of 4 LEDs each
N_LEDS = N_SITES * N_CHANNELS


def channel_index(channel: str | int) -> int:
    """Index of a channel given by name (``"nir"``) or by index (``3``)."""
    if isinstance(channel, str):
        if channel not in CHANNELS:
            raise ValueError(f"unknown channel {channel!r}; use one of {', '.join(CHANNELS)}")
        return CHANNELS.index(channel)
    index = int(channel)
    if not 0 <= index < N_CHANNELS:
        raise ValueError(f"channel index {index} out of range 0..{N_CHANNELS - 1}")
    return index


def led_index(site: int, channel: str | int) -> int:
    """Site-major LED number: ``site * 4 + channel_index``."""
    if int(site) < 0:
        raise ValueError(f"site must be >= 0, got {site}")
    return int(site) * N_CHANNELS + channel_index(channel)


def site_and_channel(led: int) -> tuple[int, int]:
    """The inverse of `led_index`: ``(site, channel index)`` of a site-major LED number."""
    if int(led) < 0:
        raise ValueError(f"LED must be >= 0, got {led}")
    return divmod(int(led), N_CHANNELS)


def n_site_subsets(n_sites: int = N_SITES) -> int:
    """The paper's site patterns: the subsets of sites with some but not all lit (254 of 8)."""
    return 2 ** int(n_sites) - 2
