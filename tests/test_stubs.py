"""What ``_evcore.pyi`` says about return values that ``mypy.stubtest`` (in ``make test``) cannot see:
it checks names and signatures against the built extension, not what methods return."""

import numpy as np
import pytest

from conftest import SAMPLES
from evservo import _evcore

RAW = SAMPLES / "prophesee_gen41_evt3_1280x720.raw"


@pytest.mark.skipif(not RAW.exists(), reason=f"{RAW} not found (set EVSERVO_SAMPLES)")
def test_raw_reader_header_is_a_list_of_pairs():
    header = _evcore.RawReader(str(RAW)).header
    assert isinstance(header, list) and header
    assert all(isinstance(k, str) and isinstance(v, str) for k, v in header)
    assert ("evt", "3.0") in header


def test_event_simulator_time_is_none_before_the_first_frame():
    sim = _evcore.EventSimulator(8, 6)
    assert sim.time_us is None
    sim.reset(np.full((6, 8), 0.5, np.float32), 1000)
    assert sim.time_us == 1000
