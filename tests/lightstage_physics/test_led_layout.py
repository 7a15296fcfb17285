"""The LED layout Pattern.msg fixes, shared by the driver, the physics and the trainer from
lightstage_graph.leds: one numbering, and the counts derived from it agree with the code that
enumerates them."""
import numpy as np
import pytest
from lightstage_graph.leds import N_CHANNELS, N_LEDS, N_SITES, led_index, n_site_subsets, site_and_channel
from lightstage_physics.rig import site_to_led_patterns


def test_site_and_channel_inverts_led_index():
    pairs = [site_and_channel(led) for led in range(N_LEDS)]
    assert [led_index(s, c) for s, c in pairs] == list(range(N_LEDS))
    assert {s for s, _ in pairs} == set(range(N_SITES))
    assert {c for _, c in pairs} == set(range(N_CHANNELS))
    with pytest.raises(ValueError):
        site_and_channel(-1)


def test_site_to_led_patterns_lights_the_leds_the_layout_names():
    site_pattern = np.zeros((N_SITES, 1))
    site_pattern[3] = 1
    leds = site_to_led_patterns(site_pattern)  # one image per channel
    for channel in range(N_CHANNELS):
        lit = np.flatnonzero(leds[:, channel])
        assert [site_and_channel(led) for led in lit] == [(3, channel)]


def test_the_trainer_nodes_candidate_count_is_what_the_search_enumerates():
    from mux_trainer.candidate_patterns import site_pattern_candidates
    assert n_site_subsets() == site_pattern_candidates().shape[1] == 254
    assert n_site_subsets(6) == site_pattern_candidates(6).shape[1]


def test_the_driver_names_an_leds_site_and_channel_from_the_layout():
    from lightstage_driver.errors import PatternError
    from lightstage_driver.patterns import validate_patterns
    pattern = np.zeros(N_LEDS)
    pattern[led_index(5, 'nir')] = np.nan
    with pytest.raises(PatternError, match=r'LED 23 \(site 5, channel 3\) is NaN'):
        validate_patterns(pattern)
