"""The positioner's air temperature: readings taken or refused, and what the compensation uses
when they are missing or stale (positioning_cell.motion.temperature)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from positioning_cell.motion.temperature import (
    TemperatureInput,
    TemperatureSettings,
    TemperatureState,
)
from positioning_cell.parameters import ParameterError

SETTINGS = TemperatureSettings(max_age=10.0, nominal=20.0, nominal_sigma=3.0,
                               sensor_sigma=0.1, drift_rate=0.01)


def test_before_any_reading_the_nominal_is_used_and_named() -> None:
    now = TemperatureInput(SETTINGS).current(5.0)
    assert now.state is TemperatureState.NOMINAL
    assert (now.value, now.sigma) == (20.0, 3.0)
    assert '/cell/air_temperature' in now.reason and 'nominal 20 degC' in now.reason


def test_a_fresh_reading_is_used_with_the_sensors_uncertainty() -> None:
    temperature = TemperatureInput(SETTINGS)
    assert temperature.update(21.5, 0.04, now=100.0) == ''
    now = temperature.current(105.0)
    assert now.state is TemperatureState.MEASURED and now.reason == ''
    assert now.value == pytest.approx(21.5)
    assert now.sigma == pytest.approx(0.2)  # sqrt(0.04)
    temperature.update(21.6, 0.0, now=106.0)  # variance 0: unknown, the floor
    assert temperature.current(106.0).sigma == pytest.approx(0.1)


def test_a_stale_reading_is_kept_with_a_widened_uncertainty_and_a_reason() -> None:
    temperature = TemperatureInput(SETTINGS)
    temperature.update(22.0, 0.01, now=0.0)
    now = temperature.current(50.0)
    assert now.state is TemperatureState.STALE and now.value == pytest.approx(22.0)
    assert now.sigma == pytest.approx(math.hypot(0.1, 0.01 * 50.0))
    assert '50 s old' in now.reason and 'stale after 10 s' in now.reason
    assert temperature.current(1e6).sigma == pytest.approx(3.0)  # never worse than nominal


@pytest.mark.parametrize(('value', 'variance', 'words'), [
    (float('nan'), 0.01, 'is not a number'),
    (21.0, float('nan'), 'is not a number'),
    (21.0, -1.0, 'is not a number'),
    (float('inf'), 0.0, 'is not a number'),
    (75.0, 0.01, 'outside -20 to 60 degC'),
    (-40.0, 0.01, 'outside -20 to 60 degC'),
])
def test_bad_readings_are_refused_with_a_reason_and_change_nothing(
        value: float, variance: float, words: str) -> None:
    temperature = TemperatureInput(SETTINGS)
    temperature.update(21.0, 0.01, now=0.0)
    reason = temperature.update(value, variance, now=1.0)
    assert words in reason and 'previous reading kept' in reason
    assert temperature.refused == 1 and temperature.last_refusal == reason
    now = temperature.current(2.0)
    assert now.value == pytest.approx(21.0) and now.state is TemperatureState.MEASURED


@given(st.floats(-20.0, 60.0), st.floats(0.0, 4.0), st.floats(0.0, 1e5))
def test_the_stated_uncertainty_never_shrinks_as_a_reading_ages(
        value: float, variance: float, age: float) -> None:
    temperature = TemperatureInput(SETTINGS)
    temperature.update(value, variance, now=0.0)
    fresh, later = temperature.current(0.0), temperature.current(age)
    assert later.value == fresh.value
    assert later.sigma >= fresh.sigma - 1e-12


def test_out_of_range_settings_are_refused_naming_the_key() -> None:
    with pytest.raises(ParameterError, match='max_age'):
        TemperatureSettings(max_age=0.0)
    with pytest.raises(ParameterError, match='nominal'):
        TemperatureSettings(nominal=99.0)
