"""evservo: event-camera 6-DoF object tracking (EDFT⁺) and visual servoing of moving objects.

Frames: ``T_a_b`` is the pose of frame b in frame a (4×4, metres); ``T_c_o`` is the object in the
camera optical frame. Time is integer microseconds. Events use OpenEB's ``EventCD`` layout.
"""

from evservo._evcore import Camera, Estimate, __version__
from evservo.models import load_object
from evservo.tracking import Tracker

__all__ = ["Camera", "Estimate", "Tracker", "__version__", "load_object"]
