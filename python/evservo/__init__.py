"""evservo: event-camera 6-DoF object tracking (EDFT+) and visual servoing of moving objects."""

from evservo._evcore import __version__

__all__ = ["__version__"]
