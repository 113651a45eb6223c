"""Event sources for the closed-loop simulation: turn the relative pose history into event batches.

A source is asked once per sensor batch for the events of ``[previous call, t_us)``, given the true
object pose in the camera frame ``T_c_o`` (4×4, metres) at ``t_us`` (µs). The episode runs the
source on every batch even while it drops the output (an injected dropout), so a source can keep
whatever per-pixel state it needs.

Sources are registered by name in :data:`EVENT_SOURCES`; a new one (e.g. a rendered ESIM camera) is
a callable with the :class:`SourceFactory` signature added there.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np

from evservo import _evcore
from evservo.synth import EdgeEventGenerator
from evservo.tracking import model_point_set


class EventSource(Protocol):
    """Produces EventCD batches from the pose history, one interval at a time."""

    def events_until(self, t_us: int, T_c_o: np.ndarray) -> np.ndarray:
        """Time-sorted EventCD events of ``[previous t_us, t_us)``; ``T_c_o`` is the object in the
        camera frame at ``t_us`` (µs, strictly increasing over calls)."""
        ...


# (camera, object, T_c_o at t0_us, t0_us, seed) -> source starting at t0_us.
SourceFactory = Callable[[_evcore.Camera, str, np.ndarray, int, int], EventSource]

# Background activity of the sensor (events/s over the whole array). 50 kev/s on 1280×720 is
# ~0.05 Hz per pixel, the low end of an IMX636 in a lit room; it keeps time stamps advancing when
# nothing moves, as on the real sensor, so the tracker's pose time tells the controller the truth.
EDGE_NOISE_RATE_HZ = 50_000.0


def edge_source(camera: _evcore.Camera, obj: str, T_c_o0: np.ndarray, t0_us: int, seed: int) -> EventSource:
    """Events where the model's dense edge points (up to 30 000, from one rendering at ``T_c_o0``)
    change pixel, plus 20 % proportional noise and :data:`EDGE_NOISE_RATE_HZ` of background."""
    dense = model_point_set(camera, obj, T_c_o0, n_points=30_000, seed=seed)
    return EdgeEventGenerator(
        camera, dense, T_c_o0, t0_us, noise_fraction=0.2, noise_rate_hz=EDGE_NOISE_RATE_HZ, seed=seed
    )


EVENT_SOURCES: dict[str, SourceFactory] = {"edges": edge_source}


def make_event_source(
    name: str, camera: _evcore.Camera, obj: str, T_c_o0: np.ndarray, t0_us: int, seed: int
) -> EventSource:
    """The source registered as ``name``, starting at ``t0_us`` (µs) with the object at ``T_c_o0``."""
    if name not in EVENT_SOURCES:
        raise ValueError(f"unknown event source {name!r}; choose one of {sorted(EVENT_SOURCES)}")
    return EVENT_SOURCES[name](camera, obj, T_c_o0, t0_us, seed)
